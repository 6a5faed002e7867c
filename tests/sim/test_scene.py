"""armpose.sim.scene: look-alike surfaces in the robot's own colours, drawn only when asked for."""
import numpy as np
import pybullet as pb
import pytest

from armpose.robots import get_robot
from armpose.sim.scene import SceneRandomizer, lookalike_colors

CFG = {"background": {"enabled": True, "textures": 2, "table_prob": 1.0, "table_height": [0.7, 0.7],
                      "walls": [1, 1], "distractors": [3, 3]}}


@pytest.fixture
def client():
    c = pb.connect(pb.DIRECT)
    yield c
    pb.disconnect(c)


def _colors(client, scene):
    """The RGBA of every body of the scene's last draw (floor collision body left out)."""
    return [tuple(round(v, 6) for v in pb.getVisualShapeData(b, physicsClientId=client)[0][7])
            for b in scene.bodies[1:]]


def test_lookalike_colors_are_the_descriptions_own():
    app = get_robot("iiwa").appearance
    colors = lookalike_colors(app)
    assert tuple(app.default_color) in colors and len(colors) == len(set(colors)) == 3   # grey, dark, orange


def test_every_table_and_distractor_is_a_lookalike_at_probability_one(client):
    colors = lookalike_colors(get_robot("iiwa").appearance)
    scene = SceneRandomizer(client, np.random.default_rng(0), {"background": {**CFG["background"], "lookalike_prob": 1.0}},
                            0.8, 2.5, colors)
    scene.new_scene()
    drawn = _colors(client, scene)
    assert len(drawn) == 4                                                  # the table and 3 distractors
    for rgba in drawn:                                  # one of the robot's colours, one brightness factor
        assert rgba[3] == 1.0
        assert any(0.85 <= (f := float(np.median(np.divide(rgba[:3], c[:3])))) <= 1.15
                   and np.allclose(np.clip(np.multiply(c[:3], f), 0, 1), rgba[:3], atol=1e-5) for c in colors)


def test_probability_zero_draws_exactly_the_scene_of_before(client):
    colors = lookalike_colors(get_robot("ur5").appearance)
    scenes = []
    for kwargs in ({}, {"lookalike_colors": colors}):
        rng = np.random.default_rng(3)
        scene = SceneRandomizer(client, rng, CFG, 0.8, 2.5, **kwargs)
        scene.new_scene()
        scenes.append((_colors(client, scene), rng.uniform()))            # same draws, same generator state
        for b in scene.bodies:
            pb.removeBody(b, physicsClientId=client)
    assert scenes[0] == scenes[1]
