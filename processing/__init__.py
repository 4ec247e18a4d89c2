"""msflash: processing."""
