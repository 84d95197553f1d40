"""Exchange formats (spec files) and scenario files."""
