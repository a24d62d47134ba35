"""Quality evaluation of extracted roof outlines and ridges against a reference (stage 11)."""
