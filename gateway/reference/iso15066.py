"""ISO/TS 15066 protective separation distance S_p, paper eq. (4)–(10).

The tests' reference of its inverse, :func:`gateway.iso15066.v_r_max_mps`.
"""

from __future__ import annotations

import numpy as np

from gateway.iso15066 import ArrayOrFloat, FloatArray


def protective_distance_m(
    v_r_mps: ArrayOrFloat,
    v_h_mps: ArrayOrFloat,
    t_r_s: ArrayOrFloat,
    a_s_mps2: ArrayOrFloat,
    c_m: ArrayOrFloat = 0.0,
    z_d_m: ArrayOrFloat = 0.0,
    z_r_m: ArrayOrFloat = 0.0,
) -> FloatArray:
    """S_p = v_h (T_r + v_r/a_s) + v_r T_r + v_r²/(2 a_s) + C + Z_d + Z_r, paper eq. (4)–(10) [m].

    Args:
        v_r_mps: robot speed toward the human at the start of the reaction [m/s].
        v_h_mps: human speed toward the robot [m/s].
        t_r_s: reaction time of the whole chain T_r [s].
        a_s_mps2: constant deceleration of the robot while stopping, > 0 [m/s²].
        c_m, z_d_m, z_r_m: intrusion distance and position uncertainties of human and robot [m].
    """
    v_r = np.asarray(v_r_mps, dtype=float)
    t_s = v_r / a_s_mps2
    return np.asarray(
        v_h_mps * (t_r_s + t_s) + v_r * t_r_s + v_r * v_r / (2.0 * np.asarray(a_s_mps2)) + c_m + z_d_m + z_r_m,
        dtype=float,
    )
