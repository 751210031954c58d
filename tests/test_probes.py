from __future__ import annotations

import numpy as np

from vecu.probes import SeriesBuffer


def test_series_buffer_keeps_rows_in_order_across_chunks_and_drops_past_capacity():
    cap = 2 * SeriesBuffer.CHUNK + 37
    buf = SeriesBuffer(3, cap)
    rows = [(k * 1e-3, float(k) ** 0.5, np.nan if k % 5 == 0 else -k) for k in range(cap + 50)]
    for k, row in enumerate(rows):
        buf.append(row)
        if k in (0, SeriesBuffer.CHUNK - 1, SeriesBuffer.CHUNK + 3):  # a view mid-way
            np.testing.assert_array_equal(buf.view(), np.array(rows[:k + 1]).T)
    got = buf.view()
    assert got.shape == (3, cap)
    np.testing.assert_array_equal(got, np.array(rows[:cap]).T)  # NaN where NaN was appended
