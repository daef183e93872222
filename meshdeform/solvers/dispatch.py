"""Serial or parallel build of a substep kernel, whichever runs faster here and now.

The serial and the parallel build of a kernel compute bit for bit the same result (the slabs
of a `SpringLayout` share no vertex, and the vertex and tether chunks below split only
element-wise work), so the choice changes the speed and never the output. It is made by
measuring, not guessed: the parallel build wins on an idle machine and loses badly when the
other cores are busy (another job, another user: each parallel launch then waits for them; see
docs/performance.md). `KernelPicker` times a few calls of each build (the fastest call of each
counts, so one interrupted call does not decide), runs the faster one, and measures again: every
PROBE_EVERY calls while the parallel build wins, sooner while the serial one does (a probe
spoiled by a moment of load on the other core is corrected within PROBE_AGAIN calls), so a run
follows the machine's load as it changes.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numba as nb
import numpy as np

#: calls of each build timed per probe (after one untimed warm-up call of each)
PROBE_CALLS = 3
#: calls between probes while the parallel build wins
PROBE_EVERY = 1500
#: calls until the next probe after the serial build won; doubled each time it wins again (up to
#: PROBE_EVERY), so a probe spoiled by a moment of load on the other core is soon corrected
PROBE_AGAIN = 50


def chunk_bounds(count: int, parts: int) -> np.ndarray:
    """(parts + 1,) uint64 bounds splitting 0..count-1 into `parts` near-equal ranges."""
    return (np.arange(parts + 1, dtype=np.uint64) * np.uint64(count)) // np.uint64(max(parts, 1))


class KernelPicker:
    """Calls `serial(*args)` or `parallel(*args)`, the one measured faster lately.

    With `parallel_ok` False (one slab, or one Numba thread) it always calls `serial`.
    """

    def __init__(self, serial: Callable[..., None], parallel: Callable[..., None], parallel_ok: bool) -> None:
        self.serial = serial
        self.parallel = parallel
        self.parallel_ok = parallel_ok and nb.get_num_threads() > 1
        self.choice: Callable[..., None] = serial
        self._phase = 0  # calls since the current probe started
        self._period = PROBE_AGAIN  # calls from one probe's start to the next
        self._probe: list[float] = [np.inf, np.inf]

    def __call__(self, *args: object) -> None:
        if not self.parallel_ok:
            self.serial(*args)
            return
        phase = self._phase
        self._phase = phase + 1 if phase + 1 < self._period else 0
        if phase >= 2 * (PROBE_CALLS + 1):
            self.choice(*args)
            return
        # probe: warm-up call of each build, then PROBE_CALLS timed calls of each, alternating
        use_parallel = phase % 2 == 1
        run = self.parallel if use_parallel else self.serial
        start = time.perf_counter()
        run(*args)
        elapsed = time.perf_counter() - start
        if phase >= 2:
            self._probe[use_parallel] = min(self._probe[use_parallel], elapsed)
        if phase == 2 * (PROBE_CALLS + 1) - 1:
            if self._probe[1] < self._probe[0]:
                self.choice, self._period = self.parallel, PROBE_EVERY
            else:
                again = self.choice is self.serial
                self.choice = self.serial
                self._period = min(2 * self._period, PROBE_EVERY) if again else PROBE_AGAIN
            self._probe = [np.inf, np.inf]

    @property
    def probing(self) -> bool:
        """Whether the next call is part of a probe (it may run either build)."""
        return self.parallel_ok and self._phase < 2 * (PROBE_CALLS + 1)

    def call_chosen(self, *args: object, worth: int = 1) -> None:
        """Call the build chosen at the last probe (not while `probing`), counted as `worth` calls.

        For calls much longer than the probed ones (a solver's whole frame after probing
        single substeps): a probe made of such calls would cost several slow frames, and
        counting each as the substeps it runs keeps the probes as frequent as substep by substep.
        """
        if self.probing:
            raise RuntimeError("call_chosen during a probe")
        if self.parallel_ok:
            phase = self._phase + max(1, worth)
            self._phase = phase if phase < self._period else 0
            self.choice(*args)
        else:
            self.serial(*args)

    def call_substeps(self, count: int, *args: object) -> None:
        """`count` substeps of a kernel whose last argument is how many substeps it runs: one
        call of the chosen build, or single substeps while probing (so a probe's calls stay short)."""
        if count > 1 and not self.probing:
            self.call_chosen(*args, count, worth=count)
        else:
            for _ in range(count):
                self(*args, 1)

    def allow_parallel(self, parallel_ok: bool) -> None:
        """A new layout (after a tear, say): keep what was measured, change only what is allowed."""
        self.parallel_ok = parallel_ok and nb.get_num_threads() > 1

    @property
    def uses_parallel(self) -> bool:
        """Whether the build chosen at the last probe is the parallel one."""
        return self.parallel_ok and self.choice is self.parallel
