"""A substep budget chosen from a target stretch (``[simulation] target_stretch``).

Why substeps and not sweeps: at the same cost, smaller steps leave a hanging cloth far less stretched than
more sweeps per step (Macklin et al. 2019, "Small Steps"; at the same sweeps per frame, 32 x 1 leaves a 256^2
hanging cloth with tethers half as stretched as 16 x 2: bench/results/convergence/h100.md). So the sweeps stay as the scene says (2 by default with a target), and
the budget doubles or halves the substeps of the next frame from the RMS structural stretch of the last one:

- over the target: double (a step may shrink by at most ``max_dt_ratio``, so doubling is the largest move);
- under a quarter of the target for ``calm_frames`` frames in a row: halve (the stretch grows two to four
  times when the steps double, so a quarter keeps a margin and does not oscillate);
- never above ``max_substeps``, nor above the float32 floor on dt when the positions are float32 ("auto"
  precision is resolved from the scene's starting budget; ``precision = "float64"`` lifts the floor), never
  below ``min_substeps`` (1 by default).

Because it reads the stretch after a frame, a load that comes at once (a cloth landing on a collider, a cloth
released from rest) stretches the frames it takes to double up to what the load needs. The report counts those
frames and names the worst; ``min_substeps`` starts the budget where it ended up, so that they are not stretched.

It starts at the scene's ``substeps``: 4, the default, or ``min_substeps`` if more, since a scene with a target
gives none (a live session that turns a target on starts from the substeps it runs at, and climbs to
``min_substeps`` a doubling a frame). The same start as a scene without a target means the same first step, and
"auto" precision is resolved from that step.

It reports what it chose: how many frames ran at each substep count, the last stretch against the target and,
when the target was missed at the cap, which cap it was and what lifts it.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

CALM_FRAMES = 10
MAX_SUBSTEPS = "max_substeps"  # what capped the budget: the scene's key ...
FLOAT32_FLOOR = "float32 floor"  # ... or the float32 floor on dt (simulator.Simulator._new_budget)


@dataclass
class Budget:
    target: float  # RMS structural stretch to stay under (a fraction: 0.01 is 1%)
    substeps: int  # for the next frame
    max_substeps: int  # the cap: the scene's max_substeps, or fewer where the float32 floor on dt is lower
    capped_by: str = MAX_SUBSTEPS  # which of the two max_substeps is: MAX_SUBSTEPS or FLOAT32_FLOOR
    calm_frames: int = CALM_FRAMES
    frames_at: Counter = field(default_factory=Counter)  # substeps -> frames run with it
    last_rms: float | None = None
    over_at_max: int = 0  # frames over the target with no substeps left to add
    min_substeps: int = 1  # the floor: halving never goes below it
    over_while_adding: int = 0  # frames over the target while substeps could still be added (a sudden load)
    worst_while_adding: tuple[float, int, int] | None = None  # (rms, frame number from 1, substeps it ran)
    _calm: int = 0

    def observe(self, rms: float, substeps: int | None = None) -> None:
        """The RMS stretch at the end of a frame run at ``substeps`` (default: the current ones); sets
        ``substeps`` for the next one. A frame run at other substeps (its stretch read a frame late, after the
        budget had moved) is counted but decides nothing: the budget already acted on the frame before it."""
        ran = self.substeps if substeps is None else substeps
        self.frames_at[ran] += 1
        self.last_rms = rms
        if ran != self.substeps:
            return
        if rms > self.target:
            self._calm = 0
            if self.substeps * 2 <= self.max_substeps:
                self.substeps *= 2
                self.over_while_adding += 1
                if self.worst_while_adding is None or rms > self.worst_while_adding[0]:
                    self.worst_while_adding = (rms, sum(self.frames_at.values()), ran)
            else:
                self.over_at_max += 1
        elif self.substeps < self.min_substeps:  # started below its floor (a live session turning a target on)
            self._calm = 0
            self.substeps = min(self.substeps * 2, self.max_substeps)
        elif rms < 0.25 * self.target and self.substeps // 2 >= self.min_substeps:
            self._calm += 1
            if self._calm >= self.calm_frames:
                self.substeps //= 2
                self._calm = 0
        else:
            self._calm = 0

    def report(self) -> str:
        """One line for the run summary."""
        chosen = ", ".join(f"{s} x {n}" for s, n in sorted(self.frames_at.items()))
        last = f"{self.last_rms:.3%}" if self.last_rms is not None else "-"
        line = f"target rms {self.target:.3%}: substeps {chosen} (substeps x frames); last frame rms {last}"
        if self.over_while_adding:
            rms, frame, ran = self.worst_while_adding
            most = max(self.frames_at)
            frames = "1 frame" if self.over_while_adding == 1 else f"{self.over_while_adding} frames"
            line += (f"; {frames} ended over the target while it added substeps (worst "
                     f"rms {rms:.3%}, frame {frame} at {ran} substeps): a load that comes at once, such as a "
                     f"landing, outruns a budget that reads the stretch after each frame")
            if most > ran:
                line += f"; min_substeps = {most} starts where it ended up"
        if self.over_at_max:
            line += f"; over the target on {self.over_at_max} frames at {self.max_substeps} substeps, "
            if self.capped_by == FLOAT32_FLOOR:
                line += ("the most the float32 floor on dt allows (a shorter step's gravity would be lost to "
                         "rounding): set precision = \"float64\" to go past it, or raise iterations")
            else:
                line += (f"the scene's max_substeps: raise max_substeps above {self.max_substeps}, or raise "
                         "iterations")
        return line
