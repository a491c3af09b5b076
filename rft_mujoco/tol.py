"""Tolerances shared across modules: each written once, here (module-specific ones live beside their use).

Every value is a plain float so that the compiled kernels can receive it as an argument (numba would
freeze a module global into its on-disk cache).
"""

TINY = 1e-300
"""Smallest magnitude treated as non-zero in a division guard (a squared norm, a diagonal)."""

TIME_RTOL = 1e-9
"""Relative tolerance on times (in units of the time step): stage times of RK4, "time advanced by at most
one step" (the rest treatment's memory of MuJoCo's previous constraint solve), grid rounding."""

VERTICAL_GRAVITY_TOL = 1e-9
"""Gravity counts as "along -z" (heightfields and bounded regions need it) when ``g_hat[2] <= -1 + this``."""

ROUND_RTOL = 1e-9
"""Relative slack when a count is the ceiling of a ratio of lengths (cells along an edge, facets along a
curve): a ratio within this of an integer rounds down to it instead of adding a sliver cell."""
