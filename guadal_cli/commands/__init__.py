"""One module per noun or verb; each exposes ``register(app)``. Commands stay thin: parse,
call the library, render."""
