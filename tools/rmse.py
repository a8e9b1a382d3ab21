"""RMSE of EXR renders against a reference EXR (the beauty RGB), for docs/PERFORMANCE.md's equal-spp
comparisons. Optional tool: `pip install OpenEXR numpy`.

    python3 tools/rmse.py REFERENCE.exr IMAGE.exr [IMAGE.exr ...]
"""
import sys

import numpy as np
import OpenEXR


def load(path):
    channels = OpenEXR.File(path).channels()
    for name in ("RGBA", "RGB"):
        if name in channels:
            return np.asarray(channels[name].pixels, dtype=np.float64)[..., :3]
    return np.stack([np.asarray(channels[c].pixels, dtype=np.float64) for c in "RGB"], -1)


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    ref = load(sys.argv[1])
    for path in sys.argv[2:]:
        img = load(path)
        rmse = np.sqrt(np.mean((img - ref) ** 2))
        print(f"{path}: RMSE {rmse:.5f}, mean {img.mean():.4f} (reference {ref.mean():.4f})")


if __name__ == "__main__":
    main()
