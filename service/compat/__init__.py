"""Fences around private APIs of dependencies: one module per library, each with check tests (tests/test_compat_*.py).
May import the libraries it fences and nothing of the project."""
