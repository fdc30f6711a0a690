"""Reports: certificates, plots and terminal summaries (no estimation here)."""
