#!/usr/bin/env python3
"""Writes the scene behind README's per-frame preparation figure ("Rendering on a farm"): a
static ground of GRID x GRID quads (2 * GRID^2 triangles: 180 000 at the default 300) and one
sphere moving over frames 1 to 10, under a camera and a distant light. Plain text, no USD
library needed.

    python3 tools/make_frames_scene.py /tmp/ground.usda [GRID]
    strata render /tmp/ground.usda --frames 1-10 --res 64x48 --spp 1 -o /tmp/g.####.exr

Each frame after the first moves the sphere's instance and builds only the top-level BVH;
the per-frame lines say so, and how long each frame took.
"""
import sys


def main():
    out = sys.argv[1]
    grid = int(sys.argv[2]) if len(sys.argv) > 2 else 300
    n = grid + 1
    points = ", ".join(
        f"({-10 + 20 * i / grid:.4f}, 0, {-10 + 20 * j / grid:.4f})" for j in range(n) for i in range(n)
    )
    counts = ", ".join("4" for _ in range(grid * grid))
    indices = ", ".join(
        f"{j * n + i}, {(j + 1) * n + i}, {(j + 1) * n + i + 1}, {j * n + i + 1}"
        for j in range(grid)
        for i in range(grid)
    )
    samples = ",\n".join(f"            {f}: ({-4 + 8 * (f - 1) / 9:.4f}, 1, 0)" for f in range(1, 11))
    with open(out, "w") as f:
        f.write(f"""#usda 1.0
(
    startTimeCode = 1
    endTimeCode = 10
    upAxis = "Y"
)

def Camera "Camera"
{{
    float focalLength = 35
    float horizontalAperture = 36
    float verticalAperture = 24
    double3 xformOp:translate = (0, 4, 14)
    float3 xformOp:rotateXYZ = (-15, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
}}

def DistantLight "Sun"
{{
    float inputs:intensity = 3
    float3 xformOp:rotateXYZ = (-50, 30, 0)
    uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
}}

def Mesh "Ground"
{{
    uniform token subdivisionScheme = "none"
    int[] faceVertexCounts = [{counts}]
    int[] faceVertexIndices = [{indices}]
    point3f[] points = [{points}]
}}

def Sphere "Ball"
{{
    double radius = 1
    double3 xformOp:translate.timeSamples = {{
{samples}
    }}
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
""")


if __name__ == "__main__":
    main()
