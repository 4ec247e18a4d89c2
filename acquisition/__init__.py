"""msflash: acquisition."""
