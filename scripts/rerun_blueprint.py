"""Writes a rerun blueprint (.rbl) for a `pipeline logs project` recording: a large 3D view of
`/world` (map and vehicles) seen nearly from above, the four bird's-eye layers `logs/bev/*` in a
2 x 2 grid, and the time panel on the `frame` timeline, paused. With --map, for a `pipeline map
import` recording: the 3D view of the map alone.

    python3 scripts/rerun_blueprint.py [--map] OUT.rbl CENTRE_X CENTRE_Y CAMERA_HEIGHT_M

CENTRE_X / CENTRE_Y: the roundabout's centre in the map's local frame (metres; the `pipeline map
info` of the map gives its roundabouts' centres). Needs `pip install rerun-sdk==0.36.3`.
"""
import sys

import rerun.blueprint as rrb


def main():
    args = sys.argv[1:]
    map_only = args[:1] == ["--map"]
    if map_only:
        args = args[1:]
    if len(args) != 4:
        sys.exit(__doc__)
    out, cx, cy, height = args[0], float(args[1]), float(args[2]), float(args[3])
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
    if map_only:
        blueprint = rrb.Blueprint(
            rrb.Spatial3DView(origin="/", name="map", eye_controls=camera),
            rrb.TimePanel(state="collapsed"),
            rrb.SelectionPanel(state="collapsed"),
            rrb.BlueprintPanel(state="expanded"),
        )
        blueprint.save("pipeline", out)
        return
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
