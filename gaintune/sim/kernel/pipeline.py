"""numba compiler pipeline of the kernel variants: copy propagation after the stages are inlined.

numba inlines an ``inline="always"`` stage at IR level by binding each of its
parameters to the caller's variable (``param = arg``). For an array, each such
copy is a reference-count increment, and its release a decrement; in a time
loop that calls a dozen stages with a dozen arrays each, LLVM's reference-count
pruning leaves many of them in place, and the single-lane kernel measured ~3x
slower. numba's parfor passes (``parallel=True``) propagate copies over the whole
function; this pipeline runs the same simplification
(:func:`numba.core.ir_utils.simplify`: copy propagation, dead-code removal, CFG
simplification) in the variants, after typing and before lowering. It
renames variables only, so the arithmetic (and every result bit) is unchanged.

numba's copy propagation snapshots its data-flow sets with ``copy.deepcopy`` on
every sweep of its fixed-point iteration: on this kernel that was ~1/5 of a
variant's compile. :func:`_copy_propagate` is the same iteration with shallow
snapshots (the sets are replaced each sweep, never changed in place, and hold
tuples of names), so it reaches the same fixed point in the same sweeps and the
compiled code is the same, instruction for instruction.
"""

from __future__ import annotations

from numba.core.analysis import compute_cfg_from_blocks
from numba.core.compiler import CompilerBase, DefaultPassBuilder
from numba.core.compiler_machinery import FunctionPass, register_pass
from numba.core.ir_utils import (
    apply_copy_propagate,
    get_name_var_table,
    init_copy_propagate_data,
    remove_dead,
    restore_copy_var_names,
    simplify_CFG,
)
from numba.core.typed_passes import NopythonRewrites, NopythonTypeInference

__all__ = ["SerialKernelCompiler"]


@register_pass(mutates_CFG=True, analysis_only=False)
class PropagateCopies(FunctionPass):
    """Whole-function copy propagation and dead-code removal, as the parfor passes do."""

    _name = "gaintune_propagate_copies"

    def __init__(self) -> None:
        FunctionPass.__init__(self)

    def run_pass(self, state) -> bool:
        _simplify(state.func_ir, state.typemap, state.calltypes)
        return True


def _copy_propagate(blocks, typemap) -> dict:
    """The copies that hold on entry to each block: :func:`numba.core.ir_utils.copy_propagate`,
    with shallow snapshots of the out-sets (see the module docstring)."""
    cfg = compute_cfg_from_blocks(blocks)
    entry = cfg.entry_point()
    gen_copies, _, kill_copies, in_copies, out_copies = init_copy_propagate_data(blocks, entry, typemap)
    old_point, new_point = None, dict(out_copies)
    while old_point != new_point:  # in_b = intersect(out of predecessors); out_b = gen_b | (in_b - kill_b)
        for label in blocks.keys():
            if label == entry:
                continue
            predecs = [i for i, _d in cfg.predecessors(label)]
            in_copies[label] = out_copies[predecs[0]].copy()
            for p in predecs:
                in_copies[label] &= out_copies[p]
            out_copies[label] = gen_copies[label] | (in_copies[label] - kill_copies[label])
        old_point, new_point = new_point, dict(out_copies)
    return in_copies


def _simplify(func_ir, typemap, calltypes) -> None:
    """:func:`numba.core.ir_utils.simplify` (copy propagation, dead code, CFG), with :func:`_copy_propagate`."""
    in_cps = _copy_propagate(func_ir.blocks, typemap)
    save_copies = apply_copy_propagate(func_ir.blocks, in_cps, get_name_var_table(func_ir.blocks), typemap, calltypes)
    restore_copy_var_names(func_ir.blocks, save_copies, typemap)
    remove_dead(func_ir.blocks, func_ir.arg_names, func_ir, typemap)
    func_ir.blocks = simplify_CFG(func_ir.blocks)


class SerialKernelCompiler(CompilerBase):
    """numba's nopython pipeline with :class:`PropagateCopies` after the typed rewrites."""

    def define_pipelines(self):
        pm = DefaultPassBuilder.define_nopython_pipeline(self.state)
        after = NopythonTypeInference if self.state.flags.no_rewrites else NopythonRewrites
        pm.add_pass_after(PropagateCopies, after)
        pm.finalize()
        return [pm]
