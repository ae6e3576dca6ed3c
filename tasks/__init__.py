"""Prefect tasks: thin adapters around one library call each."""
