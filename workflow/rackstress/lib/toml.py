"""tomllib on Python 3.11+, tomli before."""
try:
    import tomllib  # noqa: F401
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib  # noqa: F401
