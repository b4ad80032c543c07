"""Height-field objects: the surface h(x, y) interface of the paper's next world."""

import numpy as np
import pytest

from ham.errors import HamError
from ham.world import objects
from ham.world.glance import FastSimulator
from ham.world.objects import HapticObject


def test_paper_object_surface_is_its_profile_extruded():
    box = objects.get("ramp_up")
    x = np.linspace(-0.05, 0.05, 11)
    for y in (-0.04, 0.0, 0.045):
        np.testing.assert_allclose(box.surface(x, np.full_like(x, y)), box.height_at(x))
    assert not box.varies_in_y
    assert box.surface(np.array([0.0]), np.array([0.046]))[0] == 0.0  # beside the block


def test_from_surface_dome():
    def dome(x, y):
        return 0.03 - 3.0 * (x**2 + y**2)

    obj = HapticObject.from_surface("dome_t", dome, width=0.09, depth=0.09)
    assert obj.varies_in_y
    assert obj.height == pytest.approx(0.03)
    h = obj.surface(np.array([0.0, 0.02, 0.0]), np.array([0.0, 0.0, 0.02]))
    np.testing.assert_allclose(h, [0.03, 0.03 - 3.0 * 0.0004, 0.03 - 3.0 * 0.0004])
    field = obj.height_field(5, 3)
    assert field.shape == (3, 5)
    assert field[1, 2] == pytest.approx(0.03)


def test_from_height_field_is_bilinear():
    hs = np.array([[0.01, 0.02], [0.03, 0.04]])
    obj = HapticObject.from_height_field("field_t", hs, width=0.08, depth=0.06)
    np.testing.assert_allclose(
        obj.surface(np.array([-0.04, 0.04, 0.0]), np.array([-0.03, 0.03, 0.0])), [0.01, 0.04, 0.025]
    )


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: HapticObject.from_surface("s1", lambda x, y: 0.01), "returned shape"),
        (lambda: HapticObject.from_surface("s2", lambda x, y: x / 0), "not finite|failed"),
        (lambda: HapticObject.from_surface("s3", lambda x, y: np.full_like(x, 0.2)), "above"),
        (lambda: HapticObject.from_surface("s4", "dome"), "not a function"),
        (lambda: HapticObject.from_height_field("s5", [0.01, 0.02]), "2-D array"),
        (lambda: HapticObject.from_height_field("s6", [[0.01, -0.02], [0, 0]]), "below the table"),
    ],
)
def test_bad_surfaces_are_refused_by_name(make, match):
    with np.errstate(all="ignore"), pytest.raises(HamError, match=match):
        make()


def test_line_glance_refuses_height_fields():
    obj = HapticObject.from_surface("dome_r", lambda x, y: 0.03 - 3.0 * (x**2 + y**2))
    with pytest.raises(HamError, match="'dome_r' varies in y"):
        FastSimulator([obj])
