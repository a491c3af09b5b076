"""Reading the native route's table (:mod:`rft_mujoco.compiled.route`) in compiled code: its arrays as numba
arrays, without numba functions per array.

The table holds, per array, :data:`SLOT` int64 entries: the address, then up to 3 dimensions (C-contiguous,
the dtype its schema's kind says: :data:`KINDS`). Two readers, both numba intrinsics ``(t, base)``, ``t`` the
table (int64 array) and ``base`` the index of a schema's first entry:

* :func:`loader`: the tuple of the schema's arrays (or one array), each built as ``carray(address, shape)``
  builds it (C layout, not memory-managed);
* :func:`viewer`: a :class:`TableView`, two integers, whose ``view[i]`` (``i`` a constant) builds field i's
  array where it is used. The evaluation's functions index their ``md``, ``hc``, ``ws`` arguments with
  constants only, so they take a view where they took a tuple.

Why (first use, docs/performance.md "The very first compile"): with the arrays as numba functions inlined
into the route's phases (a ``carray`` each), numba's inliner, type inference and lowering spent about 10 CPU s
per phase on them; with tuples of up to 67 arrays, every copy of a tuple (each argument of an inlined
function) is an aggregate of 67 x 7 values for LLVM, and numba increfs and decrefs each array of it (2,400
reference-count calls in the rest phase, none of which does anything: the arrays are not memory-managed). A
view is two integers and holds no reference.
"""

from __future__ import annotations

from rft_mujoco.compiled.jit import AVAILABLE, types

SLOT = 4
"""Table entries per array: address, then up to 3 dimensions."""
KINDS = {"f": "float64", "i": "int64", "b": "bool", "j": "int32"}
"""dtype of each kind letter (a kind is the letter and the rank, e.g. ``"f2"``)."""


def array_type(kind: str):
    """The numba type of a table array of ``kind`` (C layout)."""
    return types.Array(getattr(types, {"bool": "boolean"}.get(KINDS[kind[0]], KINDS[kind[0]])), int(kind[1]), "C")


def _build(context, builder, data, base, offset: int, aty):
    """LLVM: the array ``aty`` from the entries ``data[base + offset:]`` (address, dimensions)."""
    from llvmlite import ir
    from numba.np.arrayobj import make_array, populate_array

    i64 = ir.IntType(64)

    def entry(k):
        return builder.load(builder.gep(data, [builder.add(base, i64(offset + k))]))

    shape = [entry(1 + d) for d in range(aty.ndim)]
    item = context.get_abi_sizeof(context.get_data_type(aty.dtype))
    strides, size = [], i64(item)
    for dim in reversed(shape):
        strides.insert(0, size)
        size = builder.mul(size, dim)
    ary = make_array(aty)(context, builder)
    populate_array(ary, data=builder.inttoptr(entry(0), context.get_data_type(aty.dtype).as_pointer()),
                   shape=shape, strides=strides, itemsize=i64(item), meminfo=None)
    return ary._getvalue()


def _table_data(context, builder, table_type, table):
    from numba.np.arrayobj import make_array

    return make_array(table_type)(context, builder, table).data


def _is_table(t) -> bool:
    return isinstance(t, types.Array) and t.dtype == types.int64 and t.ndim == 1


def loader(fields, one: bool = False):
    """An intrinsic ``(t, base) ->`` the tuple of the arrays of ``fields`` ((name, kind) pairs, one :data:`SLOT`
    each from ``base``), or the array itself when ``one``."""
    from numba.extending import intrinsic

    arrays = [array_type(kind) for _, kind in fields]
    result = arrays[0] if one else types.BaseTuple.from_types(arrays)

    def codegen(context, builder, signature, args):
        data = _table_data(context, builder, signature.args[0], args[0])
        out = [_build(context, builder, data, args[1], SLOT * i, aty) for i, aty in enumerate(arrays)]
        return out[0] if one else context.make_tuple(builder, result, out)

    @intrinsic
    def load(typingctx, t, base):
        return (result(t, types.int64), codegen) if _is_table(t) else None
    return load


if AVAILABLE:
    class TableView(types.Type):
        """The numba type of a view of a schema's table entries (:func:`viewer`): ``view[i]``, ``i`` a constant,
        is the array of field i."""

        def __init__(self, kinds):
            self.kinds = tuple(kinds)
            self.arrays = tuple(array_type(k) for k in self.kinds)
            super().__init__(name=f"TableView({','.join(self.kinds)})")

    def _register() -> None:
        from numba.core import cgutils
        from numba.core.datamodel import models, register_default
        from numba.core.imputils import lower_builtin
        from numba.core.typing.templates import AbstractTemplate, infer, signature

        @register_default(TableView)
        class _Model(models.StructModel):
            def __init__(self, dmm, fe_type):
                super().__init__(dmm, fe_type, [("data", types.CPointer(types.int64)), ("base", types.int64)])

        @infer
        class _Item(AbstractTemplate):
            key = "static_getitem"

            def generic(self, args, kws):
                view, idx = args
                if isinstance(view, TableView) and isinstance(idx, int) and 0 <= idx < len(view.arrays):
                    return signature(view.arrays[idx], *args)
                return None

        @lower_builtin("static_getitem", TableView, types.IntegerLiteral)
        def _item(context, builder, sig, args):
            view = cgutils.create_struct_proxy(sig.args[0])(context, builder, value=args[0])
            return _build(context, builder, view.data, view.base, SLOT * args[1], sig.args[0].arrays[args[1]])

    _register()
else:  # pragma: no cover - without numba nothing here is used
    TableView = None


def viewer(fields):
    """An intrinsic ``(t, base) ->`` the :class:`TableView` of ``fields`` ((name, kind) pairs) at ``base``."""
    from numba.core import cgutils
    from numba.extending import intrinsic

    view_type = TableView([kind for _, kind in fields])

    def codegen(context, builder, signature, args):
        out = cgutils.create_struct_proxy(view_type)(context, builder)
        out.data = _table_data(context, builder, signature.args[0], args[0])
        out.base = args[1]
        return out._getvalue()

    @intrinsic
    def view(typingctx, t, base):
        return (view_type(t, types.int64), codegen) if _is_table(t) else None
    return view
