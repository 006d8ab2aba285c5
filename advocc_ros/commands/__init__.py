"""Command groups of the advocc CLI."""
