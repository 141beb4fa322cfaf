"""numpy's data tags (as PyYAML's full dumper writes numpy arrays and scalars) read as plain data by a
safe loader; every other Python tag, call or argument shape refused, nothing constructed."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from sumo_scenarios.numpy_yaml import MAX_ARRAY_ELEMENTS, add_numpy_data


class PyLoader(yaml.SafeLoader):
    pass


class CLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):
    pass


LOADERS = [add_numpy_data(PyLoader), add_numpy_data(CLoader)]


@pytest.mark.parametrize("loader", LOADERS)
def test_numpy_values_dumped_by_pyyaml_read_back_as_plain_data(loader):
    values = {"grid": np.array([704, 200, 1]), "pose": np.arange(16.0).reshape(4, 4), "f32": np.float32(1.5),
              "i": np.int64(-3), "u8": np.array([1, 255], dtype=np.uint8), "bools": np.array([True, False]),
              "fortran": np.asfortranarray(np.arange(6.0).reshape(2, 3)), "empty": np.zeros((0, 3)),
              "big_endian": np.array([1.25, -2.5], dtype=">f8"), "plain": [1, "a", None]}
    read = yaml.load(yaml.dump(values), Loader=loader)
    assert read == {k: (v.tolist() if isinstance(v, np.ndarray) else v.item() if isinstance(v, np.generic) else v)
                    for k, v in values.items()}
    assert type(read["i"]) is int and type(read["f32"]) is float and type(read["grid"]) is list


DTYPE = "!!python/object/apply:numpy.dtype {args: [%s, false, true], state: !!python/tuple [3, '<', null, null, null, -1, -1, 0]}"
ARRAY = ("!!python/object/apply:numpy._core.multiarray._reconstruct {args: [!!python/name:numpy.ndarray '', "
         "!!python/tuple [0], !!binary Yg==], state: !!python/tuple [1, !!python/tuple [%s], " + DTYPE + ", false, !!binary %s]}")

REFUSED = {
    "a call of another function": "!!python/object/apply:os.system ['true']",
    "a numpy function other than the three": "!!python/object/apply:numpy.load ['x.npy']",
    "another Python name": "!!python/name:os.system ''",
    "an object built with new": "!!python/object/new:dict {}",
    "a module": "!!python/module:os ''",
    "an object dtype": DTYPE % "O",
    "a structured dtype": "!!python/object/apply:numpy.dtype {args: [f8, false, true], state: !!python/tuple [3, '<', null, [a], {a: 1}, -1, -1, 0]}",
    "fewer bytes than the shape": ARRAY % ("2", "f8", "AAAAAAAA8D8="),
    "more elements than the cap": ARRAY % (f"{MAX_ARRAY_ELEMENTS + 1}", "u1", "AA=="),
    "a negative dimension": ARRAY % ("-1", "f8", "AAAAAAAA8D8="),
    "a NaN": ARRAY % ("1", "f8", "AAAAAAAA+H8="),
    "an array from another class": ARRAY.replace("numpy.ndarray", "numpy.matrix") % ("1", "f8", "AAAAAAAA8D8="),
    "extra keys": "!!python/object/apply:numpy.dtype {args: [f8, false, true], state: !!python/tuple [3, '<', null, null, null, -1, -1, 0], listitems: [1]}",
}


@pytest.mark.parametrize("loader", LOADERS)
@pytest.mark.parametrize("case", sorted(REFUSED))
def test_every_other_python_tag_or_shape_is_refused(loader, case):
    with pytest.raises(yaml.constructor.ConstructorError):
        yaml.load("x: " + REFUSED[case], Loader=loader)


def test_the_well_formed_hand_written_array_reads():
    """The control of the refused ones: the same text with consistent bytes reads."""
    assert yaml.load("x: " + ARRAY % ("2", "f8", "AAAAAAAA8D8AAAAAAAAAQA=="), Loader=LOADERS[1]) == {"x": [1.0, 2.0]}
