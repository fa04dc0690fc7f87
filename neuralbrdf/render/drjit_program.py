"""Record the column operations of one graph evaluation once, replay them as straight-line Python.

:class:`~neuralbrdf.render.drjit_onnx.DrJitGraph` interprets an ONNX graph node by node: NumPy
object arrays of columns, broadcasting, shape folding, the unrolled matrix products.  For a given
graph what finally reaches Dr.Jit is always the same sequence of column operations (``dr.fma``
with literal weights, the rational ``tanh``, ...), yet Mitsuba traces the BSDF afresh in every
``mi.render`` call — twice per bounce (``sample`` and ``eval_pdf``) and once per wavelength —
and each trace paid the whole interpretation (``benchmarks/README.md``, design measurements).

Here the interpreter runs once, at load, with :class:`Register` placeholders in place of the
per-sample input columns.  Every column operation goes through :func:`apply`, which calls the
operation when its arguments are values and appends an instruction to the :class:`Recording`
when one of them is a register.  :meth:`Recording.compile` turns the instructions into one
Python function of straight-line code (``r7 = f2(r3, k0, r6)``, compiled once with
:func:`compile`) that issues the same operations on the same arguments in the same order: Dr.Jit
sees the identical expression, only the Python around it is gone.  Python floats given as
inputs flow through the same functions, which fold them in Python as the interpreter does.

**Several wavelengths in one call.**  A spectral BSDF evaluates its model at each of a ray's
wavelengths.  Dr.Jit merges the repeated direction part of the kernel (common-subexpression
elimination), but the Python that issues it ran once per wavelength: for the spectral NLB, whose
direction part is most of its graph, that was most of the tracing time of a render.
:meth:`Recording.compile` with ``varying`` and ``copies`` writes one function that issues the
instructions independent of the varying input once and the dependent ones once per copy.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any


class Register:
    """A column that is not known while recording: an input or an instruction's result."""

    __slots__ = ("recording", "index")

    def __init__(self, recording: Recording, index: int) -> None:
        self.recording = recording
        self.index = index

    def __repr__(self) -> str:
        return f"r{self.index}"


def apply(fn: Callable, *args: Any) -> Any:
    """``fn(*args)``, or, when an argument is a :class:`Register`, an instruction recorded for it."""
    for arg in args:
        if type(arg) is Register:
            return arg.recording.emit(fn, args)
    return fn(*args)


class Recording:
    """Instructions ``(fn, args, result register)`` in the order they were recorded."""

    def __init__(self) -> None:
        self.instructions: list[tuple[Callable, tuple, int]] = []
        self.registers = 0

    def new_register(self) -> Register:
        register = Register(self, self.registers)
        self.registers += 1
        return register

    def emit(self, fn: Callable, args: Sequence[Any]) -> Register:
        result = self.new_register()
        self.instructions.append((fn, tuple(args), result.index))
        return result

    def compile(self, inputs: Sequence[Register], outputs: Sequence[Any], varying: Register | None = None,
                copies: int = 1) -> Callable[..., list]:
        """A function of the input columns returning the output columns (registers or constants).

        Only instructions that an output depends on are kept.  With ``varying`` (one of ``inputs``)
        the function takes ``copies`` columns in its place, after the other inputs, and returns the
        outputs of each copy one after the other: the instructions that do not depend on
        ``varying`` are issued once, the others once per copy (module docstring).
        """
        needed = {o.index for o in outputs if type(o) is Register}
        kept = []
        for fn, args, result in reversed(self.instructions):
            if result in needed:
                kept.append((fn, args, result))
                needed.update(a.index for a in args if type(a) is Register)
        kept.reverse()
        dependent = set() if varying is None else {varying.index}
        for fn, args, result in kept:
            if any(type(a) is Register and a.index in dependent for a in args):
                dependent.add(result)
        names: dict[int, str] = {}
        namespace: dict[str, Any] = {}

        def name_of(value: Any, copy: int = 0) -> str:
            if type(value) is Register:
                return f"r{value.index}" + (f"_{copy}" if value.index in dependent else "")
            key = id(value)
            if key not in names:
                names[key] = f"k{len(names)}"
                namespace[names[key]] = value
            return names[key]

        def line(fn, args, result, copy=0) -> str:
            target = Register(self, result)
            return f"    {name_of(target, copy)} = {name_of(fn)}({', '.join(name_of(a, copy) for a in args)})"

        fixed = [name_of(r) for r in inputs if varying is None or r.index != varying.index]
        copies_in = [name_of(varying, c) for c in range(copies)] if varying is not None else []
        lines = [f"def program({', '.join(fixed + copies_in)}):"]
        lines += [line(fn, args, result) for fn, args, result in kept if result not in dependent]
        for copy in range(copies if varying is not None else 1):
            lines += [line(fn, args, result, copy) for fn, args, result in kept if result in dependent]
        returned = [name_of(o, c) for c in range(copies if varying is not None else 1) for o in outputs]
        lines.append(f"    return [{', '.join(returned)}]")
        # Constants (Python floats, bools) are kept alive through `namespace`, so ids stay unique.
        exec(compile("\n".join(lines), "<neuralbrdf drjit program>", "exec"), namespace)
        program = namespace["program"]
        program.instruction_count = len(lines) - 2
        return program
