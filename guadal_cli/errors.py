"""The one exception users see.

A :class:`GuadalError` says in one sentence what is wrong and what is allowed, and where:
``file`` (a mission or map) and ``field`` (a dotted path such as ``fleet.max_distance``, or a
parameter of a library call such as ``cell_size_m``). The library never names command-line
flags; the CLI maps fields to flags where they came from one (``flag``). One handler in the
app (``console.GuadalGroup``) prints the sentence without a traceback and exits with code 2; library
callers catch it like any exception.
"""

from __future__ import annotations

#: control characters a user's value may smuggle into a sentence, shown escaped (a newline in a
#: plugin name or a path must not split the sentence, nor move the terminal's cursor)
_ESCAPED = {**{i: f"\\x{i:02x}" for i in (*range(32), 127)}, 9: "\\t", 10: "\\n", 13: "\\r"}


class GuadalError(Exception):
    """Bad input or an impossible request, explained in one sentence."""

    exit_code = 2

    def __init__(self, message: str = "", *, field: str | None = None, file=None) -> None:
        message = str(message).translate(_ESCAPED)
        super().__init__(message)
        self.message = message
        self.field = None if field is None else str(field).translate(_ESCAPED)
        self.file = None if file is None else str(file).translate(_ESCAPED)
        self.flag: str | None = None

    def within(self, field: str | None = None, *, file=None) -> GuadalError:
        """The same error seen from the caller: under a parent ``field``, in ``file``.

        Returns the error itself, so a caller writes ``raise exc.within("environment")``.
        """
        if field:
            field = str(field).translate(_ESCAPED)
            self.field = f"{field}.{self.field}" if self.field else field
        if file is not None and self.file is None:
            self.file = str(file).translate(_ESCAPED)
        return self

    def __str__(self) -> str:
        where = f"{self.file}: " if self.file else ""
        if self.flag:
            return f"{where}{self.flag} {self.message}"
        return f"{where}{self.field}: {self.message}" if self.field else f"{where}{self.message}"

    def __reduce__(self):
        # keep the context when pickled (worker processes send errors back to their parent)
        return _rebuild, (type(self), self.message, self.field, self.file, self.flag)


def _rebuild(cls, message, field, file, flag) -> GuadalError:
    exc = cls(message, field=field, file=file)
    exc.flag = flag
    return exc


def _model_at(model, loc):
    """The pydantic model class reached by following ``loc`` from ``model`` (or None)."""
    import typing

    from pydantic import BaseModel

    for part in loc:
        if isinstance(part, int):
            continue
        field = getattr(model, "model_fields", {}).get(part)
        if field is None:
            return None
        candidates = [field.annotation]
        found = None
        while candidates:
            ann = candidates.pop()
            if isinstance(ann, type) and issubclass(ann, BaseModel):
                found = ann
                break
            candidates.extend(typing.get_args(ann))
        if found is None:
            return None
        model = found
    return model


def _allowed_keys(model) -> str:
    fields = getattr(model, "model_fields", {})
    return ", ".join(f.alias or name for name, f in fields.items()) if fields else "none"


def explain_validation_error(exc, model=None, prefix: str = "") -> str:
    """One sentence per pydantic error: field path, what is wrong, what is allowed."""
    sentences = []
    for err in exc.errors():
        loc = [p for p in err["loc"] if not (isinstance(p, str) and p.startswith(("function-", "union[")))]
        # unions of str|list etc. add the branch name to loc; keep the user's path only
        loc = [p for p in loc if p not in ("str", "int", "float", "list[...]", "dict[str,any]")]
        parts = ([prefix] if prefix else []) + [str(p) if not isinstance(p, int) else f"[{p}]" for p in loc]
        path = ".".join(parts).replace(".[", "[")
        kind = err["type"]
        got = err.get("input")
        if kind == "extra_forbidden":
            parent = _model_at(model, loc[:-1]) if model is not None else None
            allowed = f" (allowed: {_allowed_keys(parent)})" if parent is not None else ""
            sentences.append(f"{path}: unknown key{allowed}.")
            continue
        if kind == "missing":
            sentences.append(f"{path}: required, but missing.")
            continue
        msg = err["msg"]
        msg = msg.replace("Input should be", "must be").replace("Value error, ", "")
        msg = msg[0].lower() + msg[1:] if msg else msg
        shown = "" if isinstance(got, (dict, list)) or got is None else f" (got {got!r})"
        sentences.append(f"{path}: {msg}{shown}.")
    return " ".join(dict.fromkeys(sentences))
