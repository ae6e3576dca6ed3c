"""Prefect flows and the ``bagport`` command line."""
