"""The focus edges' gradient length: correctly rounded, the same on every call."""
import threading

import numpy as np

from cinetransfer.services.detector.focus import _magnitude_at


def _magnitude(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return _magnitude_at(x, y, np.arange(x.size)).reshape(x.shape)


def test_magnitude_of_hand_computed_gradients():
    x = np.array([3.0, 1.5, -6.0, 0.0, 1.0], np.float32)
    y = np.array([4.0, 2.0, 8.0, 0.0, 1.0], np.float32)
    assert np.array_equal(_magnitude(x, y), np.array([5.0, 2.5, 10.0, 0.0, np.sqrt(np.float32(2.0))], np.float32))


def test_magnitude_is_the_correctly_rounded_root_on_every_call_and_thread():
    # given central differences of a grey image (half grey levels), on arrays at any offset
    rng = np.random.default_rng(3)
    x = rng.integers(-255, 256, (360, 640)).astype(np.float32) / 2
    y = rng.integers(-255, 256, (360, 640)).astype(np.float32) / 2
    exact = np.sqrt(x.astype(np.float64) ** 2 + y.astype(np.float64) ** 2).astype(np.float32)
    results = []

    def at(offset: int) -> None:
        buf = np.empty(x.nbytes * 2 + 64, np.uint8)
        a = buf[offset:offset + x.nbytes].view(np.float32).reshape(x.shape)
        b = buf[x.nbytes + 32 + offset:x.nbytes + 32 + offset + y.nbytes].view(np.float32).reshape(y.shape)
        a[...], b[...] = x, y
        results.append(_magnitude(a, b))

    # when it is computed in this thread and in fresh ones
    for offset in (0, 4, 8, 12):
        at(offset)
        t = threading.Thread(target=at, args=(offset,))
        t.start()
        t.join()
    # then every result is the correctly rounded root, bit for bit (the inputs' squares are exact)
    assert len(results) == 8
    assert all(np.array_equal(r, exact) for r in results)
