"""The files users hand us and take away: maps, point clouds, floor plans, YAML."""
