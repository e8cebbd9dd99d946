"""The simulator's renderer (sim.raycast.cast and sim.scenes.make_view: each primitive intersected only in
its screen box clipped to what lies in front of the camera, the hit points gathered by index, each lighting
shaded when first asked for) gives, bit for bit, what the plain renderer below gives: every primitive
intersected with every pixel's ray, the nearest kept, every lighting shaded at once. Depth, object ids,
the three renders and the frames sensed from them are compared byte for byte over every scene, poses
turned and rolled, portrait and landscape sizes, the stereo partner's view and several seeds."""

from __future__ import annotations

import numpy as np
import pytest

from sim.raycast import Pose, Surface, pixel_rays
from sim.scenario import frame_from_view, make_model
from sim.scenes import SCENES, SceneParams, View, _charuco_pattern, build_scene, get_view, make_view
from sim.textures import LIGHTING, albedo, pattern

# (scene, shift of the camera to the right: 0 or the stereo partner's 6 cm)
CASES = [(SceneParams(scene, 3.0, 20.0, 4.0, 320, 180), shift) for scene in SCENES if scene != "person" for shift in (0.0, 0.06)] + [
    (SceneParams("person", 3.0, -20.0, 0.0, 180, 320), 0.06),
    (SceneParams("poster", 2.0, -35.0, -8.0, 480, 270, mount="wall"), 0.0),
    (SceneParams("boxes", 0.9, 45.0, 0.0, 480, 270), 0.0),
    (SceneParams("charuco", 1.2, 10.0, 0.0, 480, 270), 0.06),
    (SceneParams("poster", 7.0, 0.0, 0.0, 1280, 720, standoff_m=1.5, texture_seed=2), 0.0),  # the default size
]


def plain_view(params: SceneParams, cam, pose: Pose) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Depth (NaN = nothing), object ids and the render of every lighting, without culling or laziness."""
    spec = build_scene(params)
    D = pixel_rays(cam, pose)
    o = pose.C
    ts = np.stack([p.intersect(o, D) for p in spec.prims])  # every primitive at every pixel
    prim = np.where(np.isfinite(ts.min(axis=0)), ts.argmin(axis=0), -1)  # argmin: the first of equals, as a strict < update
    depth = np.where(prim >= 0, ts.min(axis=0), np.inf)
    surfaces = []
    for i, p in enumerate(spec.prims):
        idx = np.flatnonzero(prim.ravel() == i)
        if idx.size:
            P = o + depth.ravel()[idx, None] * D.reshape(-1, 3)[idx]
            normals, uv = p.surface(P, o)
            surfaces.append(Surface(p, idx, np.ascontiguousarray(uv), normals))
    poster_mm = (int(round(params.board_w_m * 1000)), int(round(params.board_l_m * 1000)))
    patterns = [pattern(s.prim.material, s.uv, seed=params.texture_seed, poster_mm=poster_mm) if s.prim.material != "charuco"
                else _charuco_pattern(s, cam, pose, params.charuco) for s in surfaces]
    renders = {}
    for name, light in LIGHTING.items():
        img = np.empty((cam.height * cam.width, 3), np.float32)
        img[:] = np.array([0.95, 0.85, 0.75], np.float32)
        to_light = -np.asarray(light.light_dir, np.float64)
        to_light /= np.linalg.norm(to_light)
        gain = light.exposure * np.asarray(light.tint, np.float32)
        for s, pat in zip(surfaces, patterns):
            lambert = np.maximum(s.normals @ to_light, 0.0).astype(np.float32)
            img[s.index] = albedo(s.prim.material, pat, light.contrast) * (light.ambient + light.diffuse * lambert)[..., None] * gain
        renders[name] = (np.clip(img, 0, 1) * 255.0 + 0.5).astype(np.uint8).reshape(cam.height, cam.width, 3)
    objects = tuple(dict.fromkeys(p.obj for p in spec.prims))
    lut = np.array([objects.index(p.obj) for p in spec.prims] + [-1], np.int16)
    return np.where(np.isfinite(depth), depth, np.nan), lut[prim], renders


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize(("params", "shift"), CASES, ids=[f"{p.scene}-{p.width}x{p.height}-{p.mount}-{s:g}" for p, s in CASES])
def test_the_renderer_gives_the_plain_renderers_bytes(params, shift):
    cached = get_view(params, shift)  # for its camera and pose (the one place they are made)
    view = make_view(params, build_scene(params), cached.camera, cached.pose)  # fresh: shaded here, lighting by lighting
    depth, obj, renders = plain_view(params, view.camera, view.pose)
    assert _same(view.depth, depth) and _same(view.obj, obj)
    for name in ("mixed", "indoor", "outdoor"):  # not in the presets' order: each is shaded on its own
        assert _same(view.renders[name], renders[name]), name
    assert dict(view.renders).keys() == LIGHTING.keys()


def test_frames_sensed_from_the_two_renderers_are_the_same_bytes():
    params = SceneParams("poster", 4.0, 20.0, -3.0, 640, 360)
    view = get_view(params)
    depth, obj, renders = plain_view(params, view.camera, view.pose)
    plain = View(view.params, view.camera, view.pose, depth, obj, view.objects, renders, view.spec)
    for seed, lighting in ((0, "indoor"), (1, "mixed"), (2, "outdoor"), (3, "indoor")):
        model = make_model(lighting)
        a = frame_from_view(view, model, np.random.default_rng(seed), timestamp=0.0)
        b = frame_from_view(plain, model, np.random.default_rng(seed), timestamp=0.0)
        for name in ("disparity", "confidence", "image"):
            assert _same(getattr(a, name), getattr(b, name)), (seed, name)
