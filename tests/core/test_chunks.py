"""driveopt.chunks: chunks of static sizes cover a run-time count of rows in order, without gaps or overlaps, large
first, and never reach past the capacity a buffer is given."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from driveopt.chunks import capacity, over_chunks


@pytest.mark.parametrize("sizes", [(8, 3), (12, 4), (5,)])
def test_chunks_cover_the_count_in_order_largest_first(sizes):
    rows = 40
    held = capacity(rows, sizes)

    @jax.jit
    def visits(count):
        def body(size, start, carry):  # counts how often each row is visited, and records each chunk
            seen, log, n = carry
            seen = jax.lax.dynamic_update_slice_in_dim(seen, jax.lax.dynamic_slice_in_dim(seen, start, size) + 1, start, 0)
            return seen, log.at[n].set(jnp.stack([size, start])), n + 1
        return over_chunks(count, sizes, body, (jnp.zeros(held, jnp.int32), jnp.full((held, 2), -1), 0))

    for count in (0, 1, sizes[0] - 1, sizes[0], 17, rows):
        seen, log, n = (np.asarray(a) for a in visits(count))
        log = log[:int(n)]
        assert np.all(seen[:count] == 1)  # every row once
        last = sizes[-1]
        if count == 0:
            assert len(log) == 0  # no chunk for no rows
            continue
        assert log[0, 1] == 0 and log[-1].sum() < count + last  # from row 0; past the count by less than a chunk
        assert log[-1].sum() <= held  # within the capacity (a slice past it would be shifted back, silently)
        np.testing.assert_array_equal(log[1:, 1], np.cumsum(log[:, 0])[:-1])  # contiguous
        assert list(log[:, 0]) == sorted(log[:, 0], reverse=True)  # large chunks first
        if len(sizes) > 1:
            assert sum(log[:, 0] == sizes[0]) == count // sizes[0]  # a large chunk whenever one fits
