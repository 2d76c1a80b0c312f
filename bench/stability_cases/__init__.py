"""The stability cases, shared by ``tests/test_stability.py`` (small sizes) and ``bench.stability`` (large), one
module per category: stiff, extreme_steps, loads, degenerate, over_constrained, long_runs, tethers (with small
steps), divergence, air, contact; what they share (the :class:`Check` row, scenes, energy) is in ``base``.

Each case builds its scene, runs it and returns :class:`Check` rows: a stated pass criterion, the measured
value, the bound and where the bound comes from. A check passes when ``measured <= bound`` (a NaN never
passes). Sizes differ between ``size="test"`` and ``size="bench"``; the criteria and bounds do not, unless
a case says so. ``CASES`` maps each case's name to its function, in the order the suite runs them.
"""

from .air import air_carried_sheet, air_gale, air_hurricane, air_stretched_strip, air_zero_density
from .base import SIZES, Check, count_check
from .contact import crumple, drape, fast_impact, fast_impact_line_pass
from .degenerate import coincident, small_sphere, start_inside, zero_area
from .divergence import divergence
from .extreme_steps import STEP_RANGE, dt_drop_energy, fixed_steps, frame_spike, long_stall, variable_steps
from .loads import heavy_gravity, tearing_gale
from .long_runs import long_run
from .over_constrained import pins_apart, two_places
from .stiff import bend_grid, heavy_chain, line_chain, mass_ratio, stiff_iterations, taut_line
from .tethers import small_steps, tether_energy, tether_reach

CASES = {
    "stiff_iterations": stiff_iterations,
    "bend_grid": bend_grid,
    "mass_ratio": mass_ratio,
    "heavy_chain": heavy_chain,
    "line_chain": line_chain,
    "taut_line": taut_line,
    "fixed_steps": fixed_steps,
    "variable_steps": variable_steps,
    "dt_drop_energy": dt_drop_energy,
    "frame_spike": frame_spike,
    "long_stall": long_stall,
    "heavy_gravity": heavy_gravity,
    "tearing_gale": tearing_gale,
    "coincident": coincident,
    "zero_area": zero_area,
    "small_sphere": small_sphere,
    "start_inside": start_inside,
    "pins_apart": pins_apart,
    "two_places": two_places,
    "long_run": long_run,
    "tether_reach": tether_reach,
    "tether_energy": tether_energy,
    "small_steps": small_steps,
    "divergence": divergence,
    "air_gale": air_gale,
    "air_hurricane": air_hurricane,
    "air_carried_sheet": air_carried_sheet,
    "air_stretched_strip": air_stretched_strip,
    "air_zero_density": air_zero_density,
    "drape": drape,
    "crumple": crumple,
    "fast_impact": fast_impact,
    "fast_impact_line_pass": fast_impact_line_pass,
}

__all__ = ["CASES", "SIZES", "STEP_RANGE", "Check", "count_check", *CASES]
