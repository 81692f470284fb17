"""Starting the console: resolve the database and the access policy, bind, run uvicorn.

Everything that can refuse a start (no credentials beyond loopback, a bad secrets file, an
unreachable database, a port in use) does so here, before anything listens.
"""

from __future__ import annotations

import socket
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..errors import GuadalError
from .security import Access, is_loopback, load_credentials

LOOPBACK_NAMES = ["127.0.0.1", "localhost"]


@dataclass
class ConsoleServer:
    host: str
    port: int
    app: object
    database_label: str

    @classmethod
    def configure(
        cls,
        db: str | None,
        host: str,
        port: int,
        control: bool,
        token_file: Path | None,
        tiles: str | None,
    ) -> ConsoleServer:
        from ..db.engine import ensure_schema, make_engine, redact, resolve_url
        from .app import create_app
        from .reader import ConsoleReader

        access = Access.decide(host, load_credentials(token_file), control)
        if tiles is not None and not all(k in tiles for k in ("{z}", "{x}", "{y}")):
            raise GuadalError(f"tile URL '{tiles}' must contain {{z}}, {{x}} and {{y}}.")
        url = resolve_url(db)
        if url is None:
            raise GuadalError("the console needs a database; give --db URL or set GUADAL_DB.")
        engine = make_engine(url)
        try:
            ensure_schema(engine)
        except GuadalError:
            raise
        except Exception as exc:  # the driver's own error: unreachable server, unreadable file
            raise GuadalError(f"database {redact(url)} cannot be opened ({type(exc).__name__}).") from exc
        reader = ConsoleReader(engine)
        # on loopback, only loopback names in the Host header: a page elsewhere cannot reach the
        # console by pointing its own name at 127.0.0.1 (DNS rebinding). Starlette's check reads
        # IPv4 and names only, so an IPv6 loopback console goes without it.
        allowed = LOOPBACK_NAMES + [host] if is_loopback(host) and ":" not in host else None
        app = create_app(reader, access, controls=control, tiles=tiles, allowed_hosts=allowed)
        return cls(host=host, port=port, app=app, database_label=redact(url) or "")

    def bind(self) -> socket.socket:
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((self.host.strip("[]"), self.port))
        except OSError as exc:
            sock.close()
            raise GuadalError(f"cannot listen on {self.host}:{self.port} ({exc.strerror}).") from exc
        sock.listen(64)
        return sock

    def run(self, on_ready: Callable[[str], None] | None = None) -> None:
        """Serve until interrupted; ``on_ready`` gets the console's URL once it listens."""
        import uvicorn

        sock = self.bind()
        port = sock.getsockname()[1]
        shown = f"[{self.host.strip('[]')}]" if ":" in self.host else self.host
        config = uvicorn.Config(self.app, log_level="warning", access_log=False, lifespan="off")
        server = uvicorn.Server(config)
        if on_ready is not None:
            on_ready(f"http://{shown}:{port}/")
        server.run(sockets=[sock])
