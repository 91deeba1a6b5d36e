"""The sheet's PNG written band by band as the pictures are painted (render/pictures.py
``_PngRows``, ``_Sheet``), read back by PIL's own PNG decoder."""
import numpy as np
import pytest
from PIL import Image

from rackstress.render.pictures import _PngRows


@pytest.mark.parametrize("bands", [[7], [1, 1, 5], [3, 4, 2, 1]])
def test_bands_read_back_as_one_image(tmp_path, bands):
    rng = np.random.default_rng(4)
    # noise and a smooth ramp: rows the "Up" filter changes and rows it leaves at zero
    img = rng.integers(0, 256, (sum(bands), 13, 3), dtype=np.uint8)
    img[::2] = np.arange(13, dtype=np.uint8)[None, :, None] * 19
    path = tmp_path / "x.png"
    png = _PngRows(path, 13, len(img))
    y = 0
    for n in bands:
        png.add(img[y:y + n])
        y += n
    png.close()
    with Image.open(path) as im:
        assert im.mode == "RGB" and im.size == (13, len(img))
        np.testing.assert_array_equal(np.asarray(im), img)


def test_a_missing_band_is_an_error_not_a_short_file(tmp_path):
    png = _PngRows(tmp_path / "x.png", 4, 6)
    png.add(np.zeros((5, 4, 3), np.uint8))
    with pytest.raises(RuntimeError, match="6 rows given 5"):
        png.close()
    with pytest.raises(ValueError, match="wide"):
        _PngRows(tmp_path / "y.png", 4, 2).add(np.zeros((2, 5, 3), np.uint8))
