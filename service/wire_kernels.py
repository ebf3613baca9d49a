"""The compiled part of the wire decoder (``service.messages``): kept apart so that
importing the message types does not import numba."""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["unpack_checked"]


@njit(cache=True)
def unpack_checked(seq_in, t_in, mk_in, v_in, seq, t, values):  # pragma: no cover - numba
    """Copy the packed records into ``seq``, ``t``, ``values`` (NaN where the mask bit is
    clear); False at the first record that breaks a rule of ``service.messages._bin_rows``."""
    nch = values.shape[1]
    for k in range(seq_in.shape[0]):
        s_k, t_k, m_k = seq_in[k], t_in[k], mk_in[k]
        if s_k < 0 or not np.isfinite(t_k) or m_k >= (1 << nch):
            return False
        if k > 0 and (s_k <= seq[k - 1] or t_k <= t[k - 1]):
            return False
        seq[k], t[k] = s_k, t_k
        for b in range(nch):
            if (m_k >> b) & 1:
                x = v_in[k, b]
                if not np.isfinite(x):
                    return False
                values[k, b] = x
            else:
                values[k, b] = np.nan
    return True
