"""The kernels compiled without reference counting (:data:`tdacm._jit.kernel`) return no array.

numba refuses to compile an allocation in such a kernel and refuses to return a new array
from it, but it accepts returning one of the arguments: a caller with reference counting
would then release a reference it never took. Every ``@kernel`` function of the package is
checked in its source (no argument, view of an argument or alias of one is returned) and,
for the signatures this process has compiled, in its types.
"""

import ast
import importlib
import inspect
import pkgutil
import textwrap

import numpy as np
from numba import types
from numba.core.registry import CPUDispatcher

import tdacm


def _kernels() -> dict:
    found = {}
    for info in pkgutil.walk_packages(tdacm.__path__, "tdacm."):
        if info.name.endswith("__main__"):
            continue
        mod = importlib.import_module(info.name)
        for obj in vars(mod).values():
            if isinstance(obj, CPUDispatcher) and obj.targetoptions.get("_nrt") is False:
                found[f"{obj.py_func.__module__}.{obj.py_func.__qualname__}"] = obj
    return found


def _returned_aliases(fn) -> list[str]:
    """Names returned by ``fn`` that are its arguments or bound to one (``x = a``,
    ``x = a[i]``, ``x, y = a, b``, ...)."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    func = tree.body[0]
    aliases = {a.arg for a in func.args.args}

    def roots(node):
        while isinstance(node, ast.Subscript | ast.Attribute | ast.Starred):
            node = node.value
        return {node.id} if isinstance(node, ast.Name) else set()

    for node in ast.walk(func):
        if isinstance(node, ast.Assign):
            vals = node.value.elts if isinstance(node.value, ast.Tuple) else [node.value]
            for tgt in node.targets:
                tgts = tgt.elts if isinstance(tgt, ast.Tuple) else [tgt]
                if len(vals) == len(tgts):
                    pairs = zip(tgts, vals, strict=True)
                else:  # x, y = f(a): each name may alias what is returned
                    pairs = [(t, v) for t in tgts for v in vals]
                for t, v in pairs:
                    if isinstance(t, ast.Name) and roots(v) & aliases:
                        aliases.add(t.id)
    bad = []
    for node in ast.walk(func):
        if isinstance(node, ast.Return) and node.value is not None:
            vals = node.value.elts if isinstance(node.value, ast.Tuple) else [node.value]
            bad += [n.id for v in vals for n in [v] if isinstance(n, ast.Name) and n.id in aliases]
    return bad


def _has_array(ty) -> bool:
    if isinstance(ty, types.Array):
        return True
    if isinstance(ty, types.BaseTuple):
        return any(_has_array(t) for t in ty.types)
    return False


def test_kernels_return_no_argument():
    kernels = _kernels()
    # the forward dynamics and the Lie-group helpers run without reference counting
    assert "tdacm.system.forward.forward_dynamics_ws" in kernels
    assert "tdacm.lie.blocks.expmap_rp_into" in kernels
    bad = {k: r for k, d in kernels.items() if (r := _returned_aliases(d.py_func))}
    assert not bad, f"kernels without reference counting return their arguments: {bad}"


def test_alias_check_catches_a_returned_argument():
    def leaky(a, b):
        v = a[1:]
        return v, 2.0

    def fine(a, b):
        s = a[0] + b
        return s

    assert _returned_aliases(leaky) == ["v"]
    assert _returned_aliases(fine) == []


def test_compiled_kernels_return_no_array():
    from tdacm.system import forward as F
    from tdacm.system.paper import paper_system

    system = paper_system()
    n = system.n
    q = np.zeros(n)
    q[6:] = 0.1
    m = system.model_arrays
    ok = F.forward_dynamics_ws(
        q, np.zeros(n), np.full(system.n_u, 1.0), m, system.loads.packed(), np.empty(0),
        np.empty(0), F.workspace(n, m), np.empty(n),
    )  # fmt: skip
    assert ok is True
    compiled = [k for k, d in _kernels().items() if d.nopython_signatures]
    assert "tdacm.system.forward.forward_dynamics_ws" in compiled
    bad = [
        f"{k}: {sig}"
        for k, d in _kernels().items()
        for sig in d.nopython_signatures
        if _has_array(sig.return_type)
    ]
    assert not bad, "kernels without reference counting return arrays:\n" + "\n".join(bad)
