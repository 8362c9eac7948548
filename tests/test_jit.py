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
    ``x = a[1:]``, ``x, y = a, b``, ...)."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    func = tree.body[0]
    aliases = {a.arg for a in func.args.args}

    def roots(node):
        # a name, an attribute or a slice of one aliases it (``a[i]`` of a 1-D array is a
        # number: rows taken by an index are left to the compiled types' check below)
        while isinstance(node, ast.Subscript | ast.Attribute | ast.Starred):
            if isinstance(node, ast.Subscript) and not any(
                isinstance(n, ast.Slice) for n in ast.walk(node.slice)
            ):
                return set()
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
            bad += [v.id for v in vals if isinstance(v, ast.Name) and v.id in aliases]
    return bad


def _callees(dispatcher) -> list:
    """The compiled functions ``dispatcher``'s source calls (by a name or a module attribute)."""
    fn = dispatcher.py_func
    names = fn.__globals__
    found = []
    for node in ast.walk(ast.parse(textwrap.dedent(inspect.getsource(fn)))):
        if not isinstance(node, ast.Call):
            continue
        f, obj = node.func, None
        if isinstance(f, ast.Name):
            obj = names.get(f.id)
        elif isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name):
            obj = getattr(names.get(f.value.id), f.attr, None)
        if isinstance(obj, CPUDispatcher):
            found.append(obj)
    return found


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
    assert "tdacm.system.kernels.rod_step" in kernels
    bad = {k: r for k, d in kernels.items() if (r := _returned_aliases(d.py_func))}
    assert not bad, f"kernels without reference counting return their arguments: {bad}"


def test_what_kernels_call_declares_its_runtime():
    """numba compiles a callee of a kernel without the runtime unless the callee declares its
    own (``_nrt``): an allocating callee would compile or fail by the order of first calls.
    Every function a kernel reaches (through kernels and inlined functions) is a kernel,
    inlined or declares the runtime (``tdacm._jit.allocating``)."""
    kernels = _kernels()
    stack, seen, undeclared, direct = list(kernels.values()), set(), [], set()
    while stack:
        caller = stack.pop()
        for c in _callees(caller):
            if "_nrt" in c.targetoptions and c.targetoptions["_nrt"] is True:
                direct.add(f"{c.py_func.__module__}.{c.py_func.__qualname__}")
            if id(c) in seen:
                continue
            seen.add(id(c))
            if c.targetoptions.get("inline") == "always" or c.targetoptions.get("_nrt") is False:
                stack.append(c)  # compiled in the kernel's mode: what it calls too
            elif "_nrt" not in c.targetoptions:
                undeclared.append(f"{c.py_func.__module__}.{c.py_func.__qualname__}")
    assert len(seen) > 20
    assert not undeclared, f"called from kernels, the runtime undeclared: {sorted(undeclared)}"
    # what kernels call with the runtime must return no new array (a kernel would never
    # release it): these, whose compiled return types test_kernels_compile_when_called_first
    # checks
    assert direct <= {
        "tdacm.lie.magnus.magnus_step_into",
        "tdacm.system.bodies._rotor_setup",
        "tdacm.system.bodies._node_contact",
        "tdacm.system.bodies._tip_contact",
    }, direct


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


_FIRST_CALLS = """
import numpy as np
from tdacm.system import forward as F, kernels as K
from tdacm.system.paper import paper_system

s = paper_system()
n, m = s.n, s.model_arrays
q = np.zeros(n)
q[6:] = 0.1
ws = K.make_workspace(n, m.bs.shape[3])
K.rod_step(m.h[0], m.xi0s[0], m.bs[0], q[6:], q[6:], 6, np.eye(4), np.zeros((6, n)),
           np.zeros((6, n)), np.zeros(6), np.zeros(6), True, ws)
ok = F.forward_dynamics_ws(q, np.zeros(n), np.ones(s.n_u), m, s.loads.packed(), np.empty(0),
                           np.empty(0), F.workspace(n, m), np.empty(n))
print(ok)
from numba import types
from tdacm.lie import magnus
for d in (magnus.magnus_step_into, K._rotor_setup, K._node_contact, K._tip_contact):
    for sig in d.nopython_signatures:
        rt = sig.return_type
        parts = rt.types if isinstance(rt, types.BaseTuple) else (rt,)
        assert not any(isinstance(t, types.Array) for t in parts), (d, rt)
print(ok)
"""


def test_kernels_compile_when_called_first(tmp_path):
    """On an empty cache, the kernels compile when they are the first callers of what they
    call (numba would otherwise compile an allocating callee without the runtime)."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", _FIRST_CALLS], env=env, capture_output=True,
                         text=True, timeout=600)  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().endswith("True")
