"""Modal models: decomposition of any realization, mode tables, minimality."""
