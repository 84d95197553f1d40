"""Excitation signals, periodic records, FRF estimation, data quality."""
