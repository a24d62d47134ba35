"""The ``rooftrace`` command line: thin typer commands over :mod:`rooftrace.pipeline`."""
