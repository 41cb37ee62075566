"""Data-driven visibility (Nowrouzezahrai, Kalogerakis, Fiume 2009, sec. 5)."""
