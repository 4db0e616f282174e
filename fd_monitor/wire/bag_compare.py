"""A bag against a reference bag, by decoded values within a stated tolerance.

Used where a bag is made again and compared with a shipped one (the regression suite,
``scripts/compare_regenerated.py``): the shipped library bags were simulated on another
machine, maybe with another numpy/scipy/BLAS, so byte equality held only by luck (F16XL
differed at byte 130,290, by 6.9e-18). A bag is compared record by record: topic, type and
receive time exact; each Float64MultiArray's layout (labels, sizes, data offset) and its stamp
(the padding before the data) exact, NaN where NaN (the corrupted samples), and the values
within :data:`SIM_RTOL` of the topic's largest magnitude; any other record byte for byte.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fd_monitor.wire.bag_scanner import read_raw
from fd_monitor.wire.conversions import cdr_shape
from fd_monitor.wire.topics import FLOAT64_MULTI_ARRAY

__all__ = ["SIM_RTOL", "bag_differences"]

#: Allowed difference between a simulated value here and the shipped one, relative to the
#: largest |value| on its topic. The simulator is a fixed-step scheme (exact zero-order-hold
#: discretisation of the linear modes, classical RK4 with a fixed number of substeps for the
#: nonlinear and parameter-dependent ones; noise from seeded PCG64 streams, which give the
#: same numbers on every machine): another machine runs the same operations in the same order
#: and differs only in rounding (BLAS summation order, fused multiply-add, libm's last bit),
#: ~2.2e-16 relative per operation. The shipped plants are stable, so rounding does not grow
#: along a run: a run of K <= 10^4 samples stays below K x eps ~ 2e-12 of the signal's scale
#: (measured between two CPUs: 6.9e-18 on F16XL). 1e-9 is ~500x that bound, and 1e4x below
#: the smallest relative noise bound or threshold of the shipped plants (>= 1e-5 of the
#: signal), so a change of the model, the integrator, a seed or a fault profile still fails.
SIM_RTOL = 1e-9


def bag_differences(got: str | Path, want: str | Path, rtol: float = SIM_RTOL) -> list[str]:
    """How bag ``got`` differs from the reference ``want`` (see the module docstring): one line
    per difference, the first of each record; empty when they agree.

    Parameters
    ----------
    got, want : str or pathlib.Path
        Bag folders or their ``.mcap`` files; ``want`` is the reference (the shipped bag).
    rtol : float
        Allowed |got - want| relative to the largest finite |value| of ``want``'s topic.
    """
    g, w = list(read_raw(Path(got))), list(read_raw(Path(want)))
    if len(g) != len(w):
        return [f"{len(g)} records, want {len(w)}"]
    out: list[str] = []
    parsed = []
    scale: dict[str, float] = {}
    for i, (rg, rw) in enumerate(zip(g, w, strict=True)):
        if rg[:3] != rw[:3]:
            out.append(f"record {i}: (topic, type, time) {rg[:3]}, want {rw[:3]}")
            continue
        sg = cdr_shape(rg[3]) if rw[1] == FLOAT64_MULTI_ARRAY else None
        sw = cdr_shape(rw[3]) if rw[1] == FLOAT64_MULTI_ARRAY else None
        if sw is None or sg is None:
            if rg[3] != rw[3]:
                out.append(f"record {i} ({rw[0]}): bytes differ")
            continue
        # the bytes before the data: layout (labels, sizes, strides, data offset), data count
        if sg[0] != sw[0]:
            out.append(f"record {i} ({rw[0]}): layout differs")
            continue
        dg = np.frombuffer(rg[3], "<f8", sg[3], sg[2])
        dw = np.frombuffer(rw[3], "<f8", sw[3], sw[2])
        tail = sw[2] + 8 * sw[3]
        off = sw[1].data_offset
        if rg[3][tail:] != rw[3][tail:]:
            out.append(f"record {i} ({rw[0]}): trailing bytes differ")
        elif dg[:off].tobytes() != dw[:off].tobytes():
            out.append(f"record {i} ({rw[0]}): stamp differs")
        else:
            parsed.append((i, rw[0], dg[off:], dw[off:]))
        fin = dw[off:][np.isfinite(dw[off:])]
        if fin.size:
            scale[rw[0]] = max(scale.get(rw[0], 0.0), float(np.abs(fin).max()))
    for i, topic, vg, vw in parsed:
        fin = np.isfinite(vw)
        if not np.array_equal(np.isnan(vg), np.isnan(vw)):
            out.append(f"record {i} ({topic}): NaN moved")
        elif not np.array_equal(vg[np.isinf(vw)], vw[np.isinf(vw)]):
            out.append(f"record {i} ({topic}): inf")
        elif not np.isfinite(vg[fin]).all():
            out.append(f"record {i} ({topic}): a value became non-finite")
        else:
            dev = float(np.abs(vg[fin] - vw[fin]).max()) if fin.any() else 0.0
            tol = rtol * scale.get(topic, 0.0)
            if dev > tol:
                out.append(f"record {i} ({topic}): |got - want| = {dev:.3g} > {tol:.3g} "
                           f"(rtol {rtol:g} x largest |value| {scale.get(topic, 0.0):.3g})")
    return out
