"""Figures (matplotlib, Agg backend, PNG files); import a submodule to use it."""
