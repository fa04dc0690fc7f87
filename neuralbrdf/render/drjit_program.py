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

    def compile(self, inputs: Sequence[Register], outputs: Sequence[Any]) -> Callable[..., list]:
        """A function of the input columns returning the output columns (registers or constants).

        Only instructions that an output depends on are kept.
        """
        needed = {o.index for o in outputs if type(o) is Register}
        kept = []
        for fn, args, result in reversed(self.instructions):
            if result in needed:
                kept.append((fn, args, result))
                needed.update(a.index for a in args if type(a) is Register)
        kept.reverse()
        names: dict[int, str] = {}
        namespace: dict[str, Any] = {}

        def name_of(value: Any) -> str:
            if type(value) is Register:
                return f"r{value.index}"
            key = id(value)
            if key not in names:
                names[key] = f"k{len(names)}"
                namespace[names[key]] = value
            return names[key]

        lines = [f"def program({', '.join(f'r{r.index}' for r in inputs)}):"]
        for fn, args, result in kept:
            lines.append(f"    r{result} = {name_of(fn)}({', '.join(name_of(a) for a in args)})")
        lines.append(f"    return [{', '.join(name_of(o) for o in outputs)}]")
        # Constants (Python floats, bools) are kept alive through `namespace`, so ids stay unique.
        exec(compile("\n".join(lines), "<neuralbrdf drjit program>", "exec"), namespace)
        program = namespace["program"]
        program.instruction_count = len(kept)
        return program
