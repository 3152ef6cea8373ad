"""The cpu rasterizer's reused scratch arrays: reuse without stale data, interleaved renders, no-grad renders."""

import numpy as np
import pytest
import torch

from backend.render import cpu, cpu_buffers, render
from backend.render.cpu_buffers import BufferPool
from tests.support.render_scenes import PARAMS, make_camera, random_splats, weighted_loss, with_grad


@pytest.fixture
def pool_everything(monkeypatch):
    """Pool arrays of every size (the test scenes are small), in a fresh pool."""
    monkeypatch.setattr(cpu_buffers, "SMALLEST", 0)
    monkeypatch.setattr(cpu, "POOL", BufferPool())
    return cpu.POOL


def _grads(s, cam, backend="cpu"):
    leaf = with_grad(s)
    out = render(leaf.means, leaf.quats, leaf.scales, leaf.opacities, leaf.colors, cam, backend=backend)
    weighted_loss([out]).backward()
    return out.color.detach(), {p: getattr(leaf, p).grad.clone() for p in PARAMS}


def test_pool_reuses_a_buffer_and_regrows_once_when_too_small():
    pool = BufferPool(headroom=1.5)
    a = pool.take("rows", (10_000, 10), np.float32)
    assert a.shape == (10_000, 10) and a.dtype == np.float32 and a.flags.c_contiguous
    pool.give_back("rows", a)
    b = pool.take("rows", (12_000, 10), np.float32)  # within the headroom: same buffer
    assert pool.allocations == 1 and np.shares_memory(a, b)
    pool.give_back("rows", b)
    c = pool.take("rows", (50_000, 10), np.float32)  # larger: a new one, the small one dropped
    pool.give_back("rows", c)
    assert pool.allocations == 2 and pool.held_bytes() == int(50_000 * 10 * 4 * 1.5)
    d = pool.take("isect", 100_000, np.int64)  # another name never gets the rows' buffer
    assert not np.shares_memory(c, d) and pool.allocations == 3
    e, f = pool.take("rows", (40_000, 10), np.float32), pool.take("rows", (40_000, 10), np.float32)
    assert not np.shares_memory(e, f)  # lent buffers are never lent twice


def test_the_smallest_fitting_buffer_is_taken_wherever_it_sits_among_the_free_ones():
    pool = BufferPool(headroom=1.0)
    big, small, mid = (pool.take("rows", n, np.float32) for n in (90_000, 30_000, 50_000))
    pool.give_back("rows", big, small, mid)
    got = pool.take("rows", 40_000, np.float32)  # the third free buffer (the first two do not fit best)
    assert np.shares_memory(got, mid) and pool.allocations == 3
    again = pool.take("rows", 25_000, np.float32)
    assert np.shares_memory(again, small)


def test_small_arrays_are_plain_allocations():
    pool = BufferPool()
    a = pool.take("x", 16, np.float32)
    pool.give_back("x", a)
    assert pool.allocations == 0 and pool.held_bytes() == 0


def test_repeated_training_steps_allocate_no_new_scratch_and_match_the_reference(pool_everything):
    cam = make_camera(64, 48)
    s = random_splats(600, seed=3)
    color0, g0 = _grads(s, cam)
    first = pool_everything.allocations
    assert first > 0
    # stale contents in every free buffer must not leak into the next render's results
    for bufs in pool_everything._free.values():
        for b in bufs:
            b.view(np.uint8)[:] = 0xFF  # NaN as float32, -1 as ints
    for _ in range(3):
        color, g = _grads(s, cam)
        assert torch.equal(color, color0)
        for p in PARAMS:
            assert torch.equal(g[p], g0[p]), p
    assert pool_everything.allocations == first
    ref_color, g_ref = _grads(s, cam, "reference")
    np.testing.assert_allclose(color0, ref_color, atol=2e-5)
    for p in PARAMS:
        scale = max(float(g_ref[p].abs().max()), 1e-6)
        assert float((g0[p] - g_ref[p]).abs().max()) <= 2e-4 * scale + 1e-6, p


def test_two_renders_before_their_backwards_keep_their_own_scratch(pool_everything):
    cam_a, cam_b = make_camera(64, 48), make_camera(40, 30)
    s_a, s_b = random_splats(500, seed=1), random_splats(300, seed=2)
    _, ga = _grads(s_a, cam_a)
    _, gb = _grads(s_b, cam_b)
    la, lb = with_grad(s_a), with_grad(s_b)
    out_a = render(la.means, la.quats, la.scales, la.opacities, la.colors, cam_a, backend="cpu")
    out_b = render(lb.means, lb.quats, lb.scales, lb.opacities, lb.colors, cam_b, backend="cpu")
    (weighted_loss([out_a]) + weighted_loss([out_b])).backward()
    for p in PARAMS:
        assert torch.equal(getattr(la, p).grad, ga[p]) and torch.equal(getattr(lb, p).grad, gb[p]), p


def test_a_render_without_gradients_hands_its_scratch_straight_back(pool_everything):
    cam = make_camera(64, 48)
    s = random_splats(400, seed=5)
    with torch.no_grad():
        render(s.means, s.quats, s.scales, s.opacities, s.colors, cam, backend="cpu")
    first = pool_everything.allocations
    held = pool_everything.held_bytes()
    with torch.no_grad():
        for _ in range(3):
            render(s.means, s.quats, s.scales, s.opacities, s.colors, cam, backend="cpu")
    assert pool_everything.allocations == first and pool_everything.held_bytes() == held > 0


def test_a_second_backward_through_one_render_is_refused(pool_everything):
    cam = make_camera(32, 24)
    leaf = with_grad(random_splats(100, seed=7))
    out = render(leaf.means, leaf.quats, leaf.scales, leaf.opacities, leaf.colors, cam, backend="cpu")
    loss = weighted_loss([out])
    loss.backward(retain_graph=True)
    with pytest.raises(RuntimeError, match="backward ran twice"):
        loss.backward()
