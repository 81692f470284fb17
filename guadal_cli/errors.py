"""The one exception users see.

A :class:`GuadalError` carries a single sentence that names what is wrong and what is allowed.
The CLI prints it without a traceback and exits with code 2; library callers can catch it.
"""

#: control characters a user's value may smuggle into a sentence, shown escaped (a newline in a
#: plugin name or a path must not split the sentence, nor move the terminal's cursor)
_ESCAPED = {**{i: f"\\x{i:02x}" for i in (*range(32), 127)}, 9: "\\t", 10: "\\n", 13: "\\r"}


class GuadalError(Exception):
    """Bad input or an impossible request, explained in one sentence."""

    exit_code = 2

    def __init__(self, message: str = "", *args):
        super().__init__(str(message).translate(_ESCAPED), *args)


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
