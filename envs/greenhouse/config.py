"""Static options of the greenhouse environment (a frozen, hashable dataclass).

Everything here is *static*: it changes array shapes, control flow or plain constants, so
a new value means a new compiled function. Physical and crop parameters that one may want
to vmap over live in pytrees instead (``CropParams``, ``ClimateParams``, ``WaterParams``,
``Weather``).
"""

from __future__ import annotations

import dataclasses
from typing import Literal

RewardKind = Literal["cumulative", "increment", "profit"]
REWARD_KINDS: tuple[str, ...] = ("cumulative", "increment", "profit")


@dataclasses.dataclass(frozen=True)
class GreenhouseConfig:
    """Options of one greenhouse season (paper §5.3.1, Table 1).

    Attributes:
      season_days: days (= env steps) in a season; the paper simulates "more than 160 days"
        from late December to the end of May (footnote 4).
      start_day_of_year: planting day, 1..365 (355 = 21 December). The season wraps across the
        year end: day 365 is followed by day 1 of the same weather year.
      start_day_jitter: if > 0, ``reset`` draws the planting day uniformly in
        ``start_day_of_year ± start_day_jitter`` from its key (different weather each episode);
        0 (default) makes every episode identical, as in the paper ("determined" weather).
      substeps_per_hour: internal integration steps per hour. The climate, CO2, humidity and
        water updates are exponential (exact for the linearised sub-step), hence stable for
        any step; more sub-steps only resolve the fast controller dynamics more finely.
      discrete_hours: True (Table 1): lighting/irrigation start and end are discrete hours
        0..23; False (the paper's text): continuous hours in [0, 24].
      reward: ``"cumulative"`` (the paper's: a day's reward is the cumulative harvested fruit
        fresh weight in kg/m², 0..~30), ``"increment"`` (the day's harvest in kg/m², so the
        return is the season's yield) or ``"profit"`` (the day's fruit revenue minus heating,
        CO2 and electricity costs, EUR/m²).
      weather_path: EPW or TMY3 file with one year of hourly measurements; None = pvlib's
        bundled TMY3 file of Greensboro NC (``723170TYA.CSV``).
      weather_format: ``"auto"`` (from the file name: ``.epw`` = EPW, else TMY3), ``"epw"``
        or ``"tmy3"``.
      tomato_price: EUR per kg of fresh fruit (1.5: a good price for Dutch round tomatoes).
      gas_price: EUR per MJ of heat: 0.01 = ~EUR 0.32 per m³ of natural gas (31.65 MJ/m³), the
        Dutch growers' price before 2021. At 2022 crisis prices (~0.03/MJ, with EUR 0.15/kWh)
        every way of growing this winter crop loses money, so a profit learner would learn
        to switch the greenhouse off; pass those prices to study that regime.
      co2_price: EUR per kg of pure (liquid) CO2.
      electricity_price: EUR per kWh (0.08: growers' tariff before 2021).
    """

    season_days: int = 160
    start_day_of_year: int = 355
    start_day_jitter: int = 0
    substeps_per_hour: int = 1
    discrete_hours: bool = True
    reward: RewardKind = "cumulative"
    weather_path: str | None = None
    weather_format: Literal["auto", "epw", "tmy3"] = "auto"
    tomato_price: float = 1.5
    gas_price: float = 0.01
    co2_price: float = 0.15
    electricity_price: float = 0.08

    def __post_init__(self):
        if self.reward not in REWARD_KINDS:
            raise ValueError(f"reward must be one of {list(REWARD_KINDS)}, got {self.reward!r}")
        if self.weather_format not in ("auto", "epw", "tmy3"):
            raise ValueError(
                f"weather_format must be 'auto', 'epw' or 'tmy3', got {self.weather_format!r}"
            )
        if not 1 <= self.season_days <= 365:
            raise ValueError(f"season_days must be in 1..365, got {self.season_days}")
        if not 1 <= self.start_day_of_year <= 365:
            raise ValueError(f"start_day_of_year must be in 1..365, got {self.start_day_of_year}")
        if not 0 <= self.start_day_jitter <= 180:
            raise ValueError(f"start_day_jitter must be in 0..180, got {self.start_day_jitter}")
        if not 1 <= self.substeps_per_hour <= 60:
            raise ValueError(f"substeps_per_hour must be in 1..60, got {self.substeps_per_hour}")
