"""Greenhouse tomato environment (paper §5.3, Table 1), pure JAX.

Modules, one job each: ``config`` (static options), ``weather`` (EPW/TMY3 reading),
``actions`` (Table 1 action space, schedules), ``climate`` (energy/CO2/humidity balances and
controllers), ``crop`` (reduced TOMGRO), ``water`` (slab water balance), ``simulate`` (one day
of hourly sub-steps), ``observation`` (the 225-dim normalised observation), ``env`` (the
``CompositeEnv``), ``expert`` (grower heuristic), ``season`` (whole seasons, summary, plot),
``references`` (best constant and open-loop schedules found by search on the simulator; import
it directly: it pulls in optax).
"""

from envs.greenhouse.actions import greenhouse_space
from envs.greenhouse.climate import ClimateParams
from envs.greenhouse.config import GreenhouseConfig
from envs.greenhouse.crop import CropParams
from envs.greenhouse.env import GreenhouseEnv, GreenhouseMetrics, GreenhouseSim, make_greenhouse
from envs.greenhouse.expert import expert_action
from envs.greenhouse.season import SeasonTrace, plot_season, run_season, run_seasons
from envs.greenhouse.water import WaterParams
from envs.greenhouse.weather import Weather, load_weather

__all__ = [
    "ClimateParams",
    "CropParams",
    "GreenhouseConfig",
    "GreenhouseEnv",
    "GreenhouseMetrics",
    "GreenhouseSim",
    "SeasonTrace",
    "WaterParams",
    "Weather",
    "expert_action",
    "greenhouse_space",
    "load_weather",
    "make_greenhouse",
    "plot_season",
    "run_season",
    "run_seasons",
]
