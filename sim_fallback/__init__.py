"""sim_fallback package."""
