"""The built-in methods as plugins: one module each, declaring the method's options once (a msgspec struct) and
its ``reconstruct`` function, which imports the method's implementation (``reconstruction.methods.fit``,
``.revolve``, ...) when called, so that the command line and its ``--help`` import no scipy. Each is registered
by one line of ``reconstruction/methods/__init__.py``."""
