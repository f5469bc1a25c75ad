"""Where a trained run's error on moving pixels sits: along the movers' outlines or inside them.

For each frame of a split (synthetic scenes, with ``gt/dynamic_mask``), the true moving pixels are cut into a band
``--band`` pixels wide inside the mask's outline and the interior; from the render ``radar4dgs eval`` saved
(``RUN/renders/<split>/<frame>.png``, 8-bit) and the scene's image it reports the band's share of the pixels and of
the squared error, and the PSNR of each part. A band that holds most of the error with a third of the pixels says the
movers are drawn in the right place but with soft or shifted outlines; an interior that holds it says their surface is
wrong or missing. ``--figure`` draws, for the run's frames whose band holds the largest share, the truth with the mask
outline in red, the render and the error (x3), cropped around the largest mover. Each frame also gets the largest
mover's offset (:func:`radar4dgs.evaluate.mover_offset.mover_offset`: the render's integer shift, up to ``--reach``
pixels, that best matches the truth there, and that mover's PSNR before and after it): a mover drawn off its place
gains from the shift, a soft one does not.

    python benchmarks/silhouettes.py RUN [RUN ...] [--split nvs|recon] [--band 3] [--reach 10] [--figure PNG]
                                     [--out JSON]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np
from scipy import ndimage

from radar4dgs.evaluate.mover_offset import largest_mover, mover_offset
from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.preview import save_png
from radar4dgs.io.scene import read_mask_png, read_scene

# Frames drawn by --figure, per run.
FIGURE_FRAMES = 2


def psnr_of(squared: np.ndarray) -> float | None:
    """PSNR (dB) of images in [0, 1] from their per-pixel squared errors; None for no pixel."""
    return None if squared.size == 0 else float(-10 * np.log10(max(float(squared.mean()), 1e-12)))


def outline_band(mask: np.ndarray, width: int) -> np.ndarray:
    """(H, W) bool: the pixels of ``mask`` within ``width`` pixels of its outline (the mask less its erosion)."""
    return mask & ~ndimage.binary_erosion(mask, iterations=width)


def frame_row(truth: np.ndarray, render: np.ndarray, mask: np.ndarray, width: int) -> dict:
    """(H, W, 3) images in [0, 1] and the (H, W) moving pixels: the band's pixel and error shares, PSNR of each part."""
    squared = ((truth - render) ** 2).mean(axis=-1)
    band = outline_band(mask, width)
    inner = mask & ~band
    total = float(squared[mask].sum())
    return {"pixels": int(mask.sum()), "band_pixel_share": float(band.sum() / mask.sum()),
            "band_error_share": float(squared[band].sum() / total) if total > 0 else None,
            "psnr_band": psnr_of(squared[band]), "psnr_interior": psnr_of(squared[inner]),
            "psnr_dyn": psnr_of(squared[mask])}


def crop_panel(truth: np.ndarray, render: np.ndarray, mask: np.ndarray, margin: int = 8) -> np.ndarray:
    """Truth with the mask outline in red | render | error x3, cropped around the largest connected mover."""
    rows, cols = np.nonzero(largest_mover(mask))
    top, left = max(rows.min() - margin, 0), max(cols.min() - margin, 0)
    window = np.s_[top:rows.max() + margin, left:cols.max() + margin]
    outlined = truth.copy()
    outlined[outline_band(mask, 1)] = (1.0, 0.0, 0.0)
    error = np.repeat(np.clip(np.abs(truth - render).mean(axis=-1, keepdims=True) * 3, 0, 1), 3, axis=-1)
    panel = np.concatenate([outlined[window], render[window], error[window]], axis=1)
    zoom = max(1, 160 // panel.shape[0])
    return panel.repeat(zoom, axis=0).repeat(zoom, axis=1)


def run_rows(run_dir: Path, split: str, width: int, reach: int) -> tuple[list[dict], list[np.ndarray]]:
    """Per frame of ``split`` with moving pixels: :func:`frame_row` plus ``frame`` and the largest mover's
    ``offset`` (:func:`mover_offset`); and the figure's panels."""
    scene = read_scene(json.loads((run_dir / "run.json").read_text())["scene"])
    shape = (scene.camera.height, scene.camera.width)
    rows, panels = [], []
    for entry in json.loads((run_dir / "metrics.json").read_text())["per_frame"][split]:
        name = entry["frame"]
        mask = read_mask_png(scene.root / "gt" / "dynamic_mask" / f"{name}.png", shape)
        if not mask.any():
            continue
        truth = scene.load_image(entry["index"]).astype(np.float64) / 255.0
        render = iio.imread(run_dir / "renders" / split / f"{name}.png")[..., :3].astype(np.float64) / 255.0
        rows.append({"frame": name, **frame_row(truth, render, mask, width),
                     "offset": mover_offset(truth, render, mask, reach)})
        panels.append((rows[-1]["band_error_share"] or 0.0, crop_panel(truth, render, mask)))
    chosen = [panel for _, panel in sorted(panels, key=lambda item: -item[0])[:FIGURE_FRAMES]]
    return rows, chosen


def summary(rows: list[dict]) -> dict:
    """Means over frames (the way PSNR* averages them) of each part's PSNR and of the band's shares."""
    def mean(key):
        values = [r[key] for r in rows if r[key] is not None]
        return float(np.mean(values)) if values else None
    offsets = [r["offset"] for r in rows if r.get("offset")]
    return {"frames": len(rows), **{key: mean(key) for key in
                                    ("psnr_dyn", "psnr_band", "psnr_interior", "band_pixel_share", "band_error_share")},
            "largest_mover": {
                "offset_px_median": float(np.median([o["offset_px"] for o in offsets])) if offsets else None,
                "frames_offset_2px_or_more": sum(o["offset_px"] >= 2 for o in offsets),
                "psnr": float(np.mean([o["psnr"] for o in offsets])) if offsets else None,
                "psnr_realigned": float(np.mean([o["psnr_realigned"] for o in offsets])) if offsets else None}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--split", choices=("nvs", "recon"), default="nvs")
    parser.add_argument("--band", type=int, default=3, help="width in pixels of the band inside the outline")
    parser.add_argument("--reach", type=int, default=10, help="largest shift tried for the largest mover, pixels")
    parser.add_argument("--figure", type=Path)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    result, figure = {"split": args.split, "band_px": args.band, "runs": {}}, []
    for run in args.runs:
        rows, panels = run_rows(run, args.split, args.band, args.reach)
        s = summary(rows)
        result["runs"][str(run.resolve())] = {"summary": s, "frames": rows}
        print(f"{run}: {s['frames']} frames, PSNR* {s['psnr_dyn']:.2f} dB: band {s['psnr_band']:.2f} dB "
              f"({100 * s['band_pixel_share']:.0f} % of the pixels, {100 * s['band_error_share']:.0f} % of the "
              f"squared error), interior {s['psnr_interior']:.2f} dB")
        mover = s["largest_mover"]
        if mover["psnr"] is not None:
            print(f"  largest mover: offset {mover['offset_px_median']:.1f} px (median), >= 2 px in "
                  f"{mover['frames_offset_2px_or_more']} of {s['frames']} frames; {mover['psnr']:.2f} dB, "
                  f"{mover['psnr_realigned']:.2f} realigned")
        figure += panels
    if args.figure and figure:
        width = max(panel.shape[1] for panel in figure)
        padded = [np.pad(panel, ((0, 4), (0, width - panel.shape[1]), (0, 0))) for panel in figure]
        save_png(args.figure, (np.concatenate(padded, axis=0) * 255).round().astype(np.uint8))
        print(f"wrote {args.figure}")
    if args.out:
        atomic_write_json(args.out, result)
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
