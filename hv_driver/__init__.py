"""hv_driver package."""
