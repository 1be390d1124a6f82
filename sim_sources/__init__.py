"""A simulated measurement cell: a "true" robot (nominal + hidden effects + noise) measured
by a laser tracker along a measurement program, with scenarios by name.

>>> sorted(SCENARIOS)[:3]
['backlash', 'base_frame', 'gear_periodic']
"""

from sim_sources.cell import (
    CampaignReport,
    Measurement,
    SimulatedCell,
    air_spring_force,
    simulate,
    uncalibrated_accuracy,
    write_campaign,
)
from sim_sources.program import (
    CellConfig,
    Phase,
    Program,
    ProgramConfig,
    Visit,
    make_program,
    measurable,
)
from sim_sources.scenarios import (
    SCENARIOS,
    Magnitudes,
    NoiseConfig,
    Scenario,
    get_scenario,
    list_scenarios,
    scenario_from_model,
    true_parameters,
)
from sim_sources.thermal import ThermalConfig, ThermalHistory
from sim_sources.truth import TrueRobot

__all__ = [
    "SCENARIOS",
    "CampaignReport",
    "CellConfig",
    "Magnitudes",
    "Measurement",
    "NoiseConfig",
    "Phase",
    "Program",
    "ProgramConfig",
    "Scenario",
    "SimulatedCell",
    "ThermalConfig",
    "ThermalHistory",
    "TrueRobot",
    "Visit",
    "air_spring_force",
    "get_scenario",
    "list_scenarios",
    "make_program",
    "measurable",
    "simulate",
    "scenario_from_model",
    "true_parameters",
    "uncalibrated_accuracy",
    "write_campaign",
]
