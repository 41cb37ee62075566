"""Data-driven visibility for characters and cloth (Nowrouzezahrai, Kalogerakis, Fiume 2009, sec. 5)."""

from . import stages  # noqa: F401  (registers the stage types)
