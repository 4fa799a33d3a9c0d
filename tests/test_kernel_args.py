"""The package's kernels keep short argument lists (groups that travel together are structs:
core/kernel_args.py), and a line kernel generated from its cell function takes the box, then that
function's arguments. Imports only: nothing is compiled."""

import importlib
import pkgutil

import warp as wp

import warp_mpm_bubbles
from warp_mpm_bubbles.core.grid_kernels import pressure_diagonal_and_rhs, pressure_diagonal_and_rhs_at
from warp_mpm_bubbles.core.lines import Lines

MAX_ARGUMENTS = 12


def package_kernels():
    """Every Warp kernel a module of the package holds, by name or in a dict of them (P2G, G2P)."""
    kernels = {}
    for info in pkgutil.walk_packages(warp_mpm_bubbles.__path__, "warp_mpm_bubbles."):
        module = importlib.import_module(info.name)
        for value in vars(module).values():
            for item in value.values() if isinstance(value, dict) else [value]:
                if isinstance(item, wp.Kernel):
                    kernels[(item.module.name, item.key, id(item))] = item
    return list(kernels.values())


def test_no_kernel_takes_more_than_twelve_arguments():
    kernels = package_kernels()
    assert len(kernels) > 80  # the walk found the package's kernels, not a few
    long = sorted(f"{k.module.name}.{k.key}: {len(k.adj.args)}" for k in kernels if len(k.adj.args) > MAX_ARGUMENTS)
    assert not long, f"kernels over {MAX_ARGUMENTS} arguments (group them in a struct, core/kernel_args.py): {long}"


def test_a_line_kernel_takes_the_box_then_its_cell_functions_arguments():
    args = pressure_diagonal_and_rhs.adj.args
    cell_args = list(pressure_diagonal_and_rhs_at.input_types)
    assert [a.label for a in args] == ["box", *cell_args[:-3]]
    assert cell_args[-3:] == ["i", "j", "k"]
    assert args[0].type is Lines
    assert pressure_diagonal_and_rhs.key == "pressure_diagonal_and_rhs"
