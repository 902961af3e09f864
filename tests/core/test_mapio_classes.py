"""Map pixels become the cells Nav2's map_server makes of them: unknown grey stays unknown.

``nav2_cell`` is a per-pixel transcription of ``loadMapFromFile`` in
``nav2_map_server/src/map_io.cpp`` (shade = mean of R, G, B, plus the alpha in trinary
mode; occ = 1 - shade, or shade with negate; trinary / scale / raw), and read_map must
agree with it on every pixel of random images.
"""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from sage_robot.core.mapio import DEFAULT_FREE_THRESH, read_map, write_map
from sage_robot.core.paths import package_data

from ..support.grids import grid_of

SHIPPED = package_data("maps", "campus", "map.yaml")


def nav2_cell(
    rgba: tuple[int, ...], has_alpha: bool, mode: str, negate: bool, occ_t: float, free_t: float
) -> int:
    channels = [float(v) for v in rgba[:3]]
    alpha = rgba[3] if has_alpha else 255
    if mode == "trinary" and has_alpha:
        channels.append(float(alpha))
    shade = sum(channels) / len(channels) / 255.0
    occ = shade if negate else 1.0 - shade
    if mode == "trinary":
        return 100 if occ_t < occ else 0 if occ < free_t else -1
    if mode == "scale":
        if alpha != 255:
            return -1
        if occ_t < occ:
            return 100
        if occ < free_t:
            return 0
        return int(np.rint((occ - free_t) / (occ_t - free_t) * 100.0))
    value = round(shade * 255)
    return value if 0 <= value <= 100 else -1


def write_yaml(tmp: Path, image: str, **meta: object) -> Path:
    doc = {"image": image, "resolution": 0.05, "origin": [0.0, 0.0, 0.0], **meta}
    path = tmp / "m.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


def test_grey_205_with_the_shipped_thresholds_is_unknown(tmp_path: Path) -> None:
    shipped = yaml.safe_load(SHIPPED.read_text(encoding="utf-8"))
    Image.fromarray(np.array([[0, 205, 254]], dtype=np.uint8)).save(tmp_path / "m.pgm")
    thresholds = {k: shipped[k] for k in ("occupied_thresh", "free_thresh", "negate", "mode")}
    grid = read_map(write_yaml(tmp_path, "m.pgm", **thresholds))
    assert grid.data.tolist() == [[100, -1, 0]]
    # Nav2's saver default (0.25) is what made grey free: 1 - 205/255 = 0.196 < 0.25.
    grid = read_map(write_yaml(tmp_path, "m.pgm", **{**thresholds, "free_thresh": 0.25}))
    assert grid.data.tolist() == [[100, 0, 0]]


def test_the_shipped_map_keeps_its_unknown_outside() -> None:
    grid = read_map(SHIPPED)
    pixels = np.asarray(Image.open(SHIPPED.parent / "map.pgm"))[::-1]
    assert np.array_equal(grid.data == -1, pixels == 205)
    assert (grid.data == -1).any()
    assert np.array_equal(grid.data == 0, pixels == 254)
    assert np.array_equal(grid.data == 100, pixels == 0)


def test_a_trinary_grid_round_trips_with_the_default_thresholds(tmp_path: Path) -> None:
    data = np.random.default_rng(5).choice(np.array([-1, 0, 100], dtype=np.int8), size=(30, 50))
    grid = grid_of(data, 0.05)
    path = write_map(grid, tmp_path / "rt.yaml")
    assert yaml.safe_load(path.read_text(encoding="utf-8"))["free_thresh"] == DEFAULT_FREE_THRESH
    assert np.array_equal(read_map(path).data, data)


@pytest.mark.parametrize("mode", ["trinary", "scale", "raw"])
@pytest.mark.parametrize("negate", [False, True])
@pytest.mark.parametrize("image_mode", ["L", "RGB", "RGBA", "LA"])
def test_every_pixel_as_map_io_cpp(tmp_path: Path, mode: str, negate: bool, image_mode: str) -> None:
    rng = np.random.default_rng(zlib.crc32(f"{mode}{negate}{image_mode}".encode()))
    h, w = 12, 20
    rgba = rng.integers(0, 256, size=(h, w, 4), dtype=np.uint8)
    rgba[0, :6, :3] = [[0] * 3, [100] * 3, [205] * 3, [254] * 3, [255] * 3, [50] * 3]  # the usual greys
    rgba[..., 3] = np.where(rng.random((h, w)) < 0.3, rng.integers(0, 255, size=(h, w)), 255)
    if image_mode in ("L", "LA"):
        rgba[..., 1] = rgba[..., 2] = rgba[..., 0]
    has_alpha = image_mode in ("RGBA", "LA")
    arr = {"L": rgba[..., 0], "LA": rgba[..., [0, 3]], "RGB": rgba[..., :3], "RGBA": rgba}[image_mode]
    Image.fromarray(np.ascontiguousarray(arr), image_mode).save(tmp_path / "m.png")
    occ_t, free_t = 0.65, 0.196
    grid = read_map(write_yaml(tmp_path, "m.png", mode=mode, negate=int(negate),
                               occupied_thresh=occ_t, free_thresh=free_t))  # fmt: skip
    expected = [[nav2_cell(tuple(rgba[r, c]), has_alpha, mode, negate, occ_t, free_t) for c in range(w)]
                for r in range(h)]  # fmt: skip
    assert grid.data[::-1].tolist() == expected


def test_sixteen_bit_images_are_scaled_not_clipped(tmp_path: Path) -> None:
    values = np.array([[0, 205 * 257, 65535]], dtype=np.uint16)  # 16-bit black, grey, white
    Image.fromarray(values).save(tmp_path / "m16.png")
    grid = read_map(write_yaml(tmp_path, "m16.png", occupied_thresh=0.65, free_thresh=0.196))
    assert grid.data.tolist() == [[100, -1, 0]]
