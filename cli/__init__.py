"""The `tetweave` command group (installed as tetweave_codec.cli)."""
