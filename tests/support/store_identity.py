"""The store identity the map-server store tests open their stores with."""

from __future__ import annotations

from map_server.store import StoreIdentity
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel

GRID = Grid((0.0, 0.0, 0.0), 0.1, (30, 20, 10))


IDENTITY = StoreIdentity("srvtest", GRID, SensorModel())
