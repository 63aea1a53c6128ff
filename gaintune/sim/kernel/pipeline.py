"""numba compiler pipeline of the serial kernel variants: copy propagation after the stages are inlined.

numba inlines an ``inline="always"`` stage at IR level by binding each of its
parameters to the caller's variable (``param = arg``). For an array, each such
copy is a reference-count increment, and its release a decrement; in a time
loop that calls a dozen stages with a dozen arrays each, LLVM's reference-count
pruning leaves many of them in place, and the single-lane kernel measured ~3x
slower. The parallel variant does not pay it: numba's parfor passes propagate
copies over the whole function. This pipeline runs the same simplification
(:func:`numba.core.ir_utils.simplify`: copy propagation, dead-code removal, CFG
simplification) in the serial variants, after typing and before lowering. It
renames variables only, so the arithmetic (and every result bit) is unchanged.
"""

from __future__ import annotations

from numba.core.compiler import CompilerBase, DefaultPassBuilder
from numba.core.compiler_machinery import FunctionPass, register_pass
from numba.core.ir_utils import simplify
from numba.core.typed_passes import NopythonRewrites, NopythonTypeInference

__all__ = ["SerialKernelCompiler"]


@register_pass(mutates_CFG=True, analysis_only=False)
class PropagateCopies(FunctionPass):
    """Whole-function copy propagation and dead-code removal, as the parfor passes do."""

    _name = "gaintune_propagate_copies"

    def __init__(self) -> None:
        FunctionPass.__init__(self)

    def run_pass(self, state) -> bool:
        simplify(state.func_ir, state.typemap, state.calltypes, {})
        return True


class SerialKernelCompiler(CompilerBase):
    """numba's nopython pipeline with :class:`PropagateCopies` after the typed rewrites."""

    def define_pipelines(self):
        pm = DefaultPassBuilder.define_nopython_pipeline(self.state)
        after = NopythonTypeInference if self.state.flags.no_rewrites else NopythonRewrites
        pm.add_pass_after(PropagateCopies, after)
        pm.finalize()
        return [pm]
