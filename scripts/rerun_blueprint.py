"""Writes a rerun blueprint (.rbl) for a `pipeline logs project` recording: a large 3D view of
`/world` (map and vehicles) seen nearly from above, the four bird's-eye layers `logs/bev/*` in a
2 x 2 grid, and the time panel on the `frame` timeline, paused.

    python3 scripts/rerun_blueprint.py OUT.rbl CENTRE_X CENTRE_Y CAMERA_HEIGHT_M

CENTRE_X / CENTRE_Y: the roundabout's centre in the map's local frame (metres; the `pipeline map
info` of the map gives its roundabouts' centres). Needs `pip install rerun-sdk==0.36.3`.
"""
import sys

import rerun.blueprint as rrb


def main():
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    out, cx, cy, height = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
    bev = [
        rrb.Spatial2DView(origin=f"/logs/bev/{layer}", name=f"bev/{layer}")
        for layer in ["navigable", "path", "obstacles", "stop_lines"]
    ]
    camera = rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital,
        position=[cx, cy - 0.35 * height, height],
        look_target=[cx, cy, 0.0],
        eye_up=[0, 0, 1],
    )
    blueprint = rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/world", name="world: map + vehicles", eye_controls=camera),
            rrb.Grid(*bev, grid_columns=2),
            column_shares=[2.2, 1],
        ),
        rrb.TimePanel(timeline="frame", play_state="paused", state="expanded"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.BlueprintPanel(state="expanded"),
    )
    blueprint.save("pipeline", out)


if __name__ == "__main__":
    main()
