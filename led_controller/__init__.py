"""msflash: led_controller."""
