"""One module per noun or verb, each with a module-level typer ``app`` (``app.py`` gathers them).

Commands stay thin: parse (``Annotated`` parameters), call the library, render. They let
``GuadalError`` through: the app's one boundary turns it into the sentence and exit code.
"""
