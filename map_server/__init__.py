"""map_server package."""
