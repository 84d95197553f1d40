"""Model against measurement: where a model fails, per channel and band."""
