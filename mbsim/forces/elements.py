"""Built-in force elements (registered in FORCES on import)."""
