"""File formats of tetweave (installed as tetweave_codec.formats). See README.md here for the `.tw` byte layout."""
