"""One symbolic source for the error-state filter's Jacobians (SymPy): the continuous state-transition matrix F
of the 15-state error model and the measurement rows H, derived once and generated into C
(``firmware_ref/src/generated/ins_jacobians.h``, the C core's only F and H) and Python
(``ins_hil/fusion/generated_jacobians.py``).

    python firmware_ref/tools/derive_jacobians.py           # write both files
    python firmware_ref/tools/derive_jacobians.py --check   # exit 1 if a checked-in file differs (CI)

Conventions (ins_hil.fusion, DIGEST_000 section 9): x = [δr δv ψ δb_g δb_a] (NED m, m/s, rad, body rad/s,
m/s²), δ = true − computed, Ĉ_b^n = (I + [ψ×]) C_b^n, so C_true = (I − [ψ×]) Ĉ to first order. Each model is
written as the true quantity minus the computed one, as a function of the error state; F and H are its
Jacobians at x = 0 (SymPy differentiates, nothing is linearised by hand):

* velocity: δv̇ = (I − [ψ×]) (f^n − Ĉ (δb_a + diag(f^b) δs_a)) − f^n − (2ω_ie + ω_en) × δv + (0, 0, (2g/R) δr_D)
  (the specific force through the true attitude with the true bias and scale factor, minus the computed one;
  f̃ = (1 + s) f + b, to first order in δs at the compensated f^b);
  δṙ = δv; ψ̇ = −ω_in × ψ + Ĉ (δb_g + diag(ω^b) δs_g + δG f^b) (book eq. 3.40, with the gyro scale factor and
  g-sensitivity G, row-major); δḃ = −δb/τ, δṡ = −δs/τ_s (Gauss-Markov); δĠ = 0 (random walk).
  F (15 × 15) is the base model's; the sensor-error columns (scale factors, g-sensitivity: ``F_sensor``) are the
  same model's derivatives by the extra states, generated apart so a filter without them does not pay for them.
* GNSS antenna position: r + C_true l − (r̂ + Ĉ l); velocity: v + C_true ((ω̂ − δb_g) × l) − (v̂ + Ĉ (ω̂ × l)).
* baro height: h_true − ĥ = −δr_D. ZUPT: 0 − v̂ = δv. ZARU: 0 − ω̄ = −δb_g.
* NHC: (C_true^T v_true − Ĉ^T v̂)_{y,z} with C_true^T = Ĉ^T (I + [ψ×]).
* magnetometer (book eqs. 3.28-3.38, no hard-iron states): rows 2-3 of τ (m × Ĉ_true^{-1}...) — with the unit
  reference m and Ĉ m̄ = (I + [ψ×]) m: z = rows 2-3 of τ (m × ((I + [ψ×]) m)), τ of eq. 3.33.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import NamedTuple

import sympy as sp
from sympy.printing.c import C99CodePrinter

ROOT = Path(__file__).resolve().parents[2]
C_OUT = ROOT / "firmware_ref" / "src" / "generated" / "ins_jacobians.h"
PY_OUT = ROOT / "ins_hil" / "fusion" / "generated_jacobians.py"
NX = 15


def vec(name: str) -> sp.Matrix:
    return sp.Matrix(sp.symbols(f"{name}0:3", real=True))


def skew(a: sp.Matrix) -> sp.Matrix:
    return sp.Matrix([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])


# error state: the base 15, then the sensor-error states (scale factors, gyro g-sensitivity row-major)
dr, dv, psi, dbg, dba = vec("dr"), vec("dv"), vec("psi"), vec("dbg"), vec("dba")
dsg, dsa = vec("dsg"), vec("dsa")
dG = sp.Matrix(3, 3, sp.symbols("dG0:9", real=True))
X = sp.Matrix.vstack(dr, dv, psi, dbg, dba)
XS = sp.Matrix.vstack(dsg, dsa, dG.reshape(9, 1))
NXS = NX + XS.rows  # the full layout of F_SENSOR_CELLS: [δr δv ψ δb_g δb_a δs_g δs_a δG]
ZERO = {s: 0 for s in (*X, *XS)}
# inputs
Cm = sp.Matrix(3, 3, sp.symbols("C0:9", real=True))  # C_b^n, row-major
f, wie, wen = vec("f"), vec("wie"), vec("wen")
itg, ita, its, g2r = sp.symbols("itg ita its g2r", real=True)
fb, wb = vec("fb"), vec("wb")  # compensated body specific force (m/s²) and rate (rad/s)
lev, w, v, m = vec("l"), vec("w"), vec("v"), vec("m")
I3 = sp.eye(3)


def jac(expr: sp.Matrix, by: sp.Matrix = X) -> sp.Matrix:
    return sp.simplify(expr.jacobian(by).subs(ZERO))


def _dynamics() -> sp.Matrix:
    """ẋ of the full error state [δr δv ψ δb_g δb_a δs_g δs_a δG] (module doc)."""
    coriolis = 2 * wie + wen
    w_in = wie + wen
    ddr = dv
    ddv = (
        (I3 - skew(psi)) * (f - Cm * (dba + sp.diag(*fb) * dsa))
        - f
        - coriolis.cross(dv)
        + sp.Matrix([0, 0, g2r * dr[2]])
    )
    dpsi = -w_in.cross(psi) + Cm * (dbg + sp.diag(*wb) * dsg + dG * fb)
    return sp.Matrix.vstack(ddr, ddv, dpsi, -itg * dbg, -ita * dba, -its * dsg, -its * dsa, sp.zeros(9, 1))


def derive_F() -> sp.Matrix:
    """Continuous F (15 × 15) of the base error model (module doc): ∂ẋ/∂x of the first 15 states."""
    return jac(_dynamics()[:NX, :])


def derive_F_sensor() -> sp.Matrix:
    """The sensor-error columns of F (NXS × 15): ∂ẋ/∂[δs_g δs_a δG] of every state, full layout."""
    return jac(_dynamics(), XS)


lat, rm, rn, vN, vE = sp.symbols("lat rm rn vN vE", real=True)


def derive_F_omega_rv() -> sp.Matrix:
    """The ∂ω/∂r, ∂ω/∂v terms of F (``FilterConfig.omega_rv_terms``; seed 001 eqs. 94–98 in NED), 15 × 15: what
    the position and velocity errors add through the Earth rate and the transport rate, beyond the base F.

    The true rates at the true position and velocity, with δr = (δN, δE, δD) m: φ = φ̂ + δN/(M+h),
    h = ĥ − δD (M, N held constant, as seed 001), v = v̂ + δv (v_D enters only at order v_D/R: 0):
    ω_ie = Ω (cos φ, 0, −sin φ), written with the computed (ω_ie,N, ω_ie,D) = Ω (cos φ̂, −sin φ̂) rotated by
    δN/(M+h); ω_en = (v_E/(N+h), −v_N/(M+h), −v_E tan φ/(N+h)). The attitude rows gain ∂ω_in/∂x (the true
    rate minus the computed one), the velocity rows ∂/∂x of −(2ω_ie + ω_en) × v beyond −(2ω_ie + ω_en) × δv."""
    d = dr[0] / rm
    rm_t, rn_t = rm - dr[2], rn - dr[2]
    iN, iD = wie[0], wie[2]
    w_ie_t = sp.Matrix([iN * sp.cos(d) + iD * sp.sin(d), 0, iD * sp.cos(d) - iN * sp.sin(d)])
    vt = sp.Matrix([vN + dv[0], vE + dv[1], 0])
    w_en_t = sp.Matrix([vt[1] / rn_t, -vt[0] / rm_t, -vt[1] * sp.tan(lat + d) / rn_t])
    v0 = sp.Matrix([vN, vE, 0])
    w_en_0 = w_en_t.subs(ZERO)
    datt = (w_ie_t + w_en_t) - (wie.subs({wie[1]: 0}) + w_en_0)
    c_t = 2 * w_ie_t + w_en_t
    c_0 = c_t.subs(ZERO)
    dvel = -c_t.cross(v0) + c_0.cross(v0) - (c_t - c_0).cross(dv)
    rows = sp.Matrix.vstack(sp.zeros(3, 1), dvel, datt, sp.zeros(6, 1))
    return jac(rows)


def derive_H() -> dict[str, sp.Matrix]:
    """Measurement rows H (m × 15) by measurement."""
    C_true = (I3 - skew(psi)) * Cm
    h: dict[str, sp.Matrix] = {}
    h["gnss_pos"] = jac(dr + C_true * lev - Cm * lev)
    h["gnss_vel"] = jac(dv + C_true * (w - dbg).cross(lev) - Cm * w.cross(lev))
    h["baro"] = jac(sp.Matrix([-dr[2]]))
    h["zupt"] = jac(dv)
    h["zaru"] = jac(-dbg)
    vb = Cm.T * (I3 + skew(psi)) * (v + dv) - Cm.T * v
    h["nhc"] = jac(vb[1:3, :])
    k = 1 / (1 + m[0])
    tau = sp.Matrix(
        [[m[0], m[1], m[2]], [-m[1], 1 - m[1] ** 2 * k, -m[1] * m[2] * k], [-m[2], -m[1] * m[2] * k, 1 - m[2] ** 2 * k]]
    )
    g = tau * m.cross((I3 + skew(psi)) * m)
    # the reference is a unit vector: reduce modulo |m|^2 = 1
    h["mag"] = jac(g[1:3, :]).applyfunc(lambda e: sp.factor(sp.ratsimpmodprime(e, [m.dot(m) - 1], *m)))
    return h


# the aid rows with states of their own (Python only: the C core refuses those aids): the model's true value minus
# its computed one, by the 15 base states and the aid's own states (columns 15.. of the generated row)
dw = sp.Matrix(sp.symbols("dw0:2", real=True))  # wind north, east (m/s)
deps = vec("deps")  # IMU → vehicle boresight error (R_true = (I − [δε×]) R̂)
dk = sp.Symbol("dk", real=True)  # odometer scale factor
db_m = vec("dbm")  # magnetometer hard iron (units of |m_ref|)
u, R, ub = vec("u"), sp.Matrix(3, 3, sp.symbols("R0:9", real=True)), vec("ub")
un = sp.Symbol("un", positive=True)
mu, k_hat, g_loc = sp.symbols("mu k g", real=True)
for _s in (*dw, *deps, dk, *db_m):
    ZERO[_s] = 0


def jac_ext(expr: sp.Matrix, extra: sp.Matrix) -> sp.Matrix:
    """∂expr/∂[x, extra] at zero, not simplified (the aid rows are short)."""
    return expr.jacobian(sp.Matrix.vstack(X, extra)).subs(ZERO).applyfunc(sp.factor_terms)


def derive_H_aids() -> dict[str, sp.Matrix]:
    """The aid rows with their own states (module doc conventions; u: the computed quantity the row is taken at)."""
    C_true_T = Cm.T * (I3 + skew(psi))  # C_true^T = Ĉ^T (I + [ψ×])
    h: dict[str, sp.Matrix] = {}
    # true airspeed |v − w| (u = v̂ − ŵ, NED; the wind horizontal), by [x, δw_N, δw_E]
    ut = u + dv - sp.Matrix([dw[0], dw[1], 0])
    h["airspeed"] = jac_ext(sp.Matrix([sp.sqrt(ut.dot(ut))]), dw)
    # odometer speed (1 + k) (C^T v)_x, by [x, δk]
    h["odometer"] = jac_ext(sp.Matrix([(1 + k_hat + dk) * (C_true_T * (v + dv))[0]]), sp.Matrix([dk]))
    # multirotor drag on the bias-compensated specific force: −μ (C^T (v − w))_xy + δb_a,xy, by [x, δw_N, δw_E]
    fd = -mu * (C_true_T * ut)[0:2, :] + dba[0:2, :]
    h["drag"] = jac_ext(fd, dw)
    # NHC at a reference point in vehicle axes: R (C^T v + ω × l), rows y, z (ω = ω̂ − δb_g), by [x, δε]
    u_ref = (I3 - skew(deps)) * R * (C_true_T * (v + dv) + (w - dbg).cross(lev))
    h["nhc_mounted"] = jac_ext(u_ref[1:3, :], deps)
    # ground-vehicle longitudinal acceleration: the kinematic acceleration along the vehicle's forward axis,
    # (R (f_b − δb_a + C^T g))_x with g = (0, 0, g) NED (Coriolis and transport rate left out), by x only
    a_b = fb - dba + C_true_T * sp.Matrix([0, 0, g_loc])
    h["long_accel"] = jac_ext((R * a_b)[0:1, :], sp.zeros(0, 1))
    # magnetometer hard iron: rows 2-3 of τ (m × Ĉ ū), ū = (u + δb_m)/|u + δb_m| (u = |u| ū: the corrected field,
    # the computed u = u_true + δb_m), and the magnitude −|u + δb_m|, by δb_m only (the ψ columns: H_mag); ū is a
    # unit vector (reduced modulo |ū|² = 1)
    k = 1 / (1 + m[0])
    tau = sp.Matrix(
        [[m[0], m[1], m[2]], [-m[1], 1 - m[1] ** 2 * k, -m[1] * m[2] * k], [-m[2], -m[1] * m[2] * k, 1 - m[2] ** 2 * k]]
    )
    ut_b = un * ub + db_m
    nb = sp.sqrt(ut_b.dot(ut_b))
    g = tau * m.cross(Cm * (ut_b / nb))
    jb = sp.Matrix.vstack(g[1:3, :], sp.Matrix([-nb])).jacobian(db_m).subs(ZERO)
    h["mag_bias"] = jb.applyfunc(lambda e: sp.factor_terms(sp.factor_terms(e).subs(ub.dot(ub), 1)))
    return h


# the arguments of each generated function: (name, symbols) in order
F_ARGS = [("C", list(Cm)), ("f_ned", list(f)), ("w_ie", list(wie)), ("w_en", list(wen)),
          ("inv_tau_g", [itg]), ("inv_tau_a", [ita]), ("g2r", [g2r])]  # fmt: skip
FRV_ARGS = [("w_ie", list(wie)), ("lat", [lat]), ("rm", [rm]), ("rn", [rn]), ("vN", [vN]), ("vE", [vE])]
FS_ARGS = [("C", list(Cm)), ("f_b", list(fb)), ("w_b", list(wb)), ("inv_tau_s", [its])]
H_ARGS = {
    "gnss_pos": [("C", list(Cm)), ("lever", list(lev))],
    "gnss_vel": [("C", list(Cm)), ("omega_b", list(w)), ("lever", list(lev))],
    "baro": [],
    "zupt": [],
    "zaru": [],
    "nhc": [("C", list(Cm)), ("vel", list(v))],
    "mag": [("m", list(m))],
}
H_DOC = {
    "gnss_pos": "GNSS antenna position (lever arm l, body FRD, m): δr + [(C l)×] ψ",
    "gnss_vel": "GNSS antenna velocity (compensated body rate ω, rad/s): δv + [(C(ω×l))×] ψ + C [l×] δb_g",
    "baro": "barometric height: −δr_D",
    "zupt": "zero velocity: δv",
    "zaru": "zero angular rate: −δb_g",
    "nhc": "non-holonomic constraint (body y, z velocity): C^T δv − C^T [v×] ψ",
    "mag": "magnetometer, unit reference field m (NED): rows 2-3 of τ (book eq. 3.33) on ψ",
}


HA_ARGS = {
    "airspeed": [("u", list(u))],
    "odometer": [("C", list(Cm)), ("vel", list(v)), ("k", [k_hat])],
    "drag": [("C", list(Cm)), ("u", list(u)), ("mu", [mu])],
    "nhc_mounted": [("C", list(Cm)), ("vel", list(v)), ("R", list(R)), ("omega_b", list(w)), ("lever", list(lev))],
    "mag_bias": [("m", list(m)), ("C", list(Cm)), ("ubar", list(ub)), ("un", [un])],
    "long_accel": [("C", list(Cm)), ("R", list(R)), ("g", [g_loc])],
}
HA_DOC = {
    "airspeed": "true airspeed |v − w| at u = v̂ − ŵ (NED m/s): u^T δv / |u| − u_NE^T δw / |u|; columns 15-16: the wind",
    "odometer": "odometer speed (1 + k) (C^T v)_x: (1 + k) (C^T δv − C^T [v×] ψ)_x + (C^T v)_x δk; column 15: δk",
    "drag": "multirotor drag −μ (C^T u)_xy + δb_a,xy, u = v̂ − ŵ: −μ C^T δv + μ C^T [u×] ψ + μ C^T δw; "
    "columns 15-16: the wind",
    "nhc_mounted": "NHC at a reference point, vehicle axes y, z: R C^T δv − R C^T [v×] ψ + R [l×] δb_g + [û×] δε; "
    "columns 15-17: the boresight",
    "mag_bias": "magnetometer hard iron (3 × 3, by δb_m; ū = u/|u|, un = |u|): rows 2-3 of τ [m×] C (I − ū ū^T)/|u|, "
    "magnitude −ū^T",
    "long_accel": "ground-vehicle forward kinematic acceleration (R (f_b + C^T g))_x, g = (0, 0, g) NED: "
    "−R (C^T [g×] ψ + δb_a), row x; no states of its own",
}
HA_EXTRA = {"airspeed": 2, "odometer": 1, "drag": 2, "nhc_mounted": 3, "mag_bias": 0, "long_accel": 0}


def _subs_c(args: list[tuple[str, list[sp.Symbol]]]) -> dict[sp.Symbol, sp.Symbol]:
    out = {}
    for name, syms in args:
        for i, s in enumerate(syms):
            out[s] = sp.Symbol(f"{name}[{i}]") if len(syms) > 1 else sp.Symbol(name)
    return out


class _CPrinter(C99CodePrinter):
    """C99 in the scalar type ins_real: integer powers as products, no double literals (float build)."""

    def _print_Pow(self, e: sp.Pow) -> str:
        b, n = e.as_base_exp()
        if n.is_Integer and 0 < int(n) <= 3:
            return "*".join([self.parenthesize(b, 60)] * int(n))
        if n == -1:
            return f"((ins_real)1/{self.parenthesize(b, 60)})"
        raise ValueError(f"derive_jacobians: no C form for the power {e}")

    def _print_Rational(self, e: sp.Rational) -> str:
        return f"((ins_real){e.p}/(ins_real){e.q})"

    def _print_Float(self, e: sp.Float) -> str:
        raise ValueError(f"derive_jacobians: a float literal {e} in a Jacobian")


def _c_expr(e: sp.Expr, sub: dict[sp.Symbol, sp.Symbol]) -> str:
    return str(_CPrinter().doprint(sp.sympify(e).xreplace(sub)))


def _entries(M: sp.Matrix) -> list[tuple[int, int, sp.Expr]]:
    return [(i, j, M[i, j]) for i in range(M.rows) for j in range(M.cols) if M[i, j] != 0]


def _c_blocks(M: sp.Matrix, blocks: dict[str, tuple[int, int]], sub: dict[sp.Symbol, sp.Symbol]) -> list[str]:
    """The assignments of each 3 × 3 block ``b->name`` of M (top-left corner (r0, c0))."""
    return [f"    b->{name}[{i}][{j}] = {_c_expr(M[r0 + i, c0 + j], sub)};"
            for name, (r0, c0) in blocks.items() for i in range(3) for j in range(3)]  # fmt: skip


def gen_c(F: sp.Matrix, H: dict[str, sp.Matrix], FS: sp.Matrix) -> str:
    out = [
        "/* GENERATED by firmware_ref/tools/derive_jacobians.py from one SymPy derivation - do not edit.",
        " * The Jacobians of the 15-state error-state filter (ins_ref.h): F (continuous, block form) and the",
        " * measurement rows H. tests/test_generated_jacobians.py regenerates and diffs this file. */",
        "#ifndef INS_GENERATED_JACOBIANS_H",
        "#define INS_GENERATED_JACOBIANS_H",
        '#include "ins_ref.h"',
        "",
        "/* F = dẋ/dx at x = 0. Structure (checked by the generator): F[0:3][3:6] = I, F[9+i][9+i] = -1/tau_g,",
        " * F[12+i][12+i] = -1/tau_a, and the blocks below (rows/columns of the velocity, attitude, bias states). */",
        "typedef struct {",
        "    ins_real vr_dd;        /* F[5][2]: d(dv_D)/d(dr_D) */",
        "    ins_real vv[3][3];     /* F[3:6][3:6] */",
        "    ins_real va[3][3];     /* F[3:6][6:9] */",
        "    ins_real vba[3][3];    /* F[3:6][12:15] */",
        "    ins_real aa[3][3];     /* F[6:9][6:9] */",
        "    ins_real abg[3][3];    /* F[6:9][9:12] */",
        "} ins_gen_fblocks_t;",
        "",
        "static inline void ins_gen_F_blocks(const ins_real C[9], const ins_real f_ned[3], const ins_real w_ie[3],",
        "                                    const ins_real w_en[3], ins_real g2r, ins_gen_fblocks_t *b) {",
    ]
    sub = _subs_c(F_ARGS)
    out += _c_blocks(F, {"vv": (3, 3), "va": (3, 6), "vba": (3, 12), "aa": (6, 6), "abg": (6, 9)}, sub)
    out.append(f"    b->vr_dd = {_c_expr(F[5, 2], sub)};")
    out.append("}")
    out += [
        "",
        "/* The scale-factor columns of F (21-state layout: states 15-17 = gyro, 18-20 = accelerometer scale factor);",
        " * their own rows are -1/tau_s on the diagonal (checked by the generator). */",
        "typedef struct {",
        "    ins_real asg[3][3];    /* F[6:9][15:18] */",
        "    ins_real vsa[3][3];    /* F[3:6][18:21] */",
        "} ins_gen_fsf_t;",
        "",
        "static inline void ins_gen_F_sf(const ins_real C[9], const ins_real f_b[3], const ins_real w_b[3],",
        "                                ins_gen_fsf_t *b) {",
    ]
    out += _c_blocks(FS, {"asg": (6, 0), "vsa": (3, 3)}, _subs_c(FS_ARGS))
    out.append("}")
    for name, M in H.items():
        args = H_ARGS[name]
        sub = _subs_c(args)
        params = "".join(f"const ins_real {a}[{len(s)}], " if len(s) > 1 else f"ins_real {a}, " for a, s in args)
        out += ["", f"/* {H_DOC[name]}. Writes the nonzero entries of rows 0..{M.rows - 1} (zero h first). */",
                f"static inline void ins_gen_H_{name}({params}ins_real h[][INS_NX]) {{"]  # fmt: skip
        out += [f"    h[{i}][{j}] = {_c_expr(e, sub)};" for i, j, e in _entries(M)]
        out.append("}")
    out += ["", "#endif"]
    return "\n".join(out) + "\n"


def _py_expr(e: sp.Expr, sub: dict[sp.Symbol, sp.Symbol]) -> str:
    return sp.pycode(sp.sympify(e).xreplace(sub))


class _Cells(NamedTuple):
    """One sparse F section of the Python module: a ``NAME_CELLS`` table and its ``NAME_values`` function."""

    name: str  # F, F_SENSOR, F_OMEGA_RV (the function: F_values, F_sensor_values, ...)
    comment: tuple[str, ...]  # the "#:" lines above the cells table
    entries: list[tuple[int, int, sp.Expr]]  # (row, column in the layout, expression)
    args: list[tuple[str, list[sp.Symbol]]]
    signature: tuple[str, ...]  # the def's parameter lines (after "def NAME_values(")
    doc: tuple[str, ...]  # the docstring's lines


def _py_cells(c: _Cells) -> list[str]:
    """The cells table and the values function of one sparse F section."""
    fn = "F" if c.name == "F" else c.name[:2] + c.name[2:].lower()
    out = [*(f"#: {line}" for line in c.comment), f"{c.name}_CELLS: tuple[tuple[int, int], ...] = ("]
    out += [f"    ({i}, {j})," for i, j, _ in c.entries]
    pad = " " * len(f"def {fn}_values(")
    out += [")", "", "", f"def {fn}_values({c.signature[0]}", *(pad + line for line in c.signature[1:])]
    out += [f'    """{c.doc[0]}', *(f"    {line}" for line in c.doc[1:-1]), f'    {c.doc[-1]}"""', "    return ("]
    sub = _subs_c(c.args)
    out += [f"        {_py_expr(e, sub)}," for _, _, e in c.entries]
    return [*out, "    )"]


def _py_rows(name: str, M: sp.Matrix, args: list[tuple[str, list[sp.Symbol]]], doc: str, cols: str) -> list[str]:
    """``H_name(...)``: the rows of a measurement model as a fresh array (``cols`` columns)."""
    sub = _subs_c(args)
    params = ", ".join(f"{a}: Any" if len(s) > 1 else f"{a}: float" for a, s in args)  # array-like
    # the vectors as Python floats (scalar arithmetic on numpy scalars is several times slower)
    pre = [f"    {a} = np.asarray({a}, dtype=np.float64).ravel().tolist()" for a, sy in args if len(sy) > 1]
    shape = f"{M.rows} × 15" if cols == "NX" else f"{M.rows} × {cols}"
    out = ["", "", f"def H_{name}({params}) -> np.ndarray:", f'    """{doc} ({shape})."""']
    out += [*pre, f"    h = np.zeros(({M.rows}, {cols}))"]
    out += [f"    h[{i}, {j}] = {_py_expr(e, sub)}" for i, j, e in _entries(M)]
    return [*out, "    return h"]


def _py_dense(fn: str, params: tuple[str, ...], doc: str, n: str, vals: str) -> list[str]:
    """A function building the dense matrix of a sparse F section from its cells and values."""
    pad = " " * len(f"def {fn}(")
    return ["", "", f"def {fn}({params[0]}", *(pad + line for line in params[1:]), f'    """{doc}"""',
            f"    out = np.zeros(({n}, {n}))", "    c = np.asarray(C, dtype=np.float64).ravel().tolist()",
            f"    vals = {vals}", f"    out.put([i * {n} + j for i, j in {fn.upper()}_CELLS], vals)",
            "    return out", "", ""]  # fmt: skip


def gen_py(F: sp.Matrix, H: dict[str, sp.Matrix], FS: sp.Matrix, FR: sp.Matrix, HA: dict[str, sp.Matrix]) -> str:
    out = [
        "# ruff: noqa: E501",
        "# fmt: off",
        '"""GENERATED by firmware_ref/tools/derive_jacobians.py from one SymPy derivation - do not edit.',
        "",
        "The Jacobians of the 15-state error-state filter (layout of ``ins_hil.fusion.ekf`` with the gyro and",
        "accelerometer bias states only): the continuous F and the measurement rows H, the same derivation as the",
        "C core's ``firmware_ref/src/generated/ins_jacobians.h``. Vectors are 3-sequences of floats; C = C_b^n.",
        '"""',
        "",
        "from __future__ import annotations",
        "",
        "import math",
        "from collections.abc import Sequence",
        "from typing import Any",
        "",
        "import numpy as np",
        "",
        f"NX = {NX}",
        "",
        "",
    ]
    out += _py_cells(_Cells(
        "F", ("the (row, column) of every entry of F that is not identically zero, in the order of :func:`F_values`",),
        _entries(F), F_ARGS,
        ("C: Sequence[float], f_ned: Sequence[float], w_ie: Sequence[float], w_en: Sequence[float],",
         "inv_tau_g: float, inv_tau_a: float, g2r: float) -> tuple[float, ...]:"),
        ("The entries of F at :data:`F_CELLS` (C: the 9 entries of C_b^n row by row, floats): one",
         "``ndarray.put`` fills a caller-owned F (the hot path: no array built per step)."),
    ))  # fmt: skip
    out += _py_dense("F", ("C: np.ndarray, f_ned: Sequence[float], w_ie: Sequence[float], w_en: Sequence[float],",
                           "inv_tau_g: float, inv_tau_a: float, g2r: float) -> np.ndarray:"),
                     "Continuous error-dynamics matrix F (15 × 15) at the nominal state (C: 3 × 3 C_b^n).", "NX",
                     "F_values(c, f_ned, w_ie, w_en, inv_tau_g, inv_tau_a, g2r)")  # fmt: skip
    out += [
        f"#: the full layout of the sensor-error columns: {NX} base states, gyro / accelerometer scale factors,",
        "#: gyro g-sensitivity (row-major)",
        f"NXS = {NXS}",
    ]
    out += _py_cells(_Cells(
        "F_SENSOR",
        ("the (row, column) in that layout of every entry of the scale-factor and g-sensitivity columns of F that is",
         "not identically zero, in the order of :func:`F_sensor_values`"),
        [(i, NX + j, e) for i, j, e in _entries(FS)], FS_ARGS,
        ("C: Sequence[float], f_b: Sequence[float], w_b: Sequence[float],", "inv_tau_s: float) -> tuple[float, ...]:"),
        ("The entries of F at :data:`F_SENSOR_CELLS` (C: C_b^n row by row; f_b, w_b: the compensated body",
         "specific force and rate; inv_tau_s: 1 / the scale factors' correlation time)."),
    ))  # fmt: skip
    out += _py_dense("F_sensor",
                     ("C: np.ndarray, f_b: Sequence[float], w_b: Sequence[float], inv_tau_s: float) -> np.ndarray:",),
                     "The sensor-error columns of F in the full layout (NXS × NXS; the base columns zero).", "NXS",
                     "F_sensor_values(c, [float(x) for x in f_b], [float(x) for x in w_b], inv_tau_s)")  # fmt: skip
    out += _py_cells(_Cells(
        "F_OMEGA_RV",
        ("the (row, column) of every entry the ∂ω/∂r, ∂ω/∂v terms add to F (15-state layout; omega_rv_terms), in",
         "the order of :func:`F_omega_rv_values`"),
        _entries(FR), FRV_ARGS,
        ("w_ie: Sequence[float], lat: float, rm: float, rn: float, vN: float,", "vE: float) -> tuple[float, ...]:"),
        ("What the ∂ω/∂r, ∂ω/∂v terms add to F at :data:`F_OMEGA_RV_CELLS` (w_ie: the Earth rate NED, rad/s;",
         "lat rad; rm, rn: M + h, N + h, m; vN, vE: the velocity, m/s)."),
    ))  # fmt: skip
    for name, M in H.items():
        out += _py_rows(name, M, H_ARGS[name], H_DOC[name], "NX")
    for name, M in HA.items():
        out += _py_rows(name, M, HA_ARGS[name], HA_DOC[name], str(M.cols))
    return "\n".join(out) + "\n"


def check_structure(F: sp.Matrix) -> None:
    """The block structure the C core's block-sparse predict (ekf.c phi_blocks, phi_p_phit) relies on."""
    allowed = set()
    for i in range(3):
        allowed.add((i, 3 + i))
        assert F[i, 3 + i] == 1
        assert F[9 + i, 9 + i] == -itg and F[12 + i, 12 + i] == -ita
        allowed |= {(9 + i, 9 + i), (12 + i, 12 + i)}
    for r0, c0 in ((3, 3), (3, 6), (3, 12), (6, 6), (6, 9)):
        allowed |= {(r0 + i, c0 + j) for i in range(3) for j in range(3)}
    allowed.add((5, 2))
    for r0, c0 in ((3, 3), (3, 6), (6, 6)):  # F_vv, F_vpsi, F_psipsi skew: ekf.c's m3 skips their zero diagonal
        for i in range(3):
            assert F[r0 + i, c0 + i] == 0 and F[r0 + i, c0 + (i + 1) % 3] == -F[r0 + (i + 1) % 3, c0 + i]
    extra = [(i, j) for i, j, _ in _entries(F) if (i, j) not in allowed]
    if extra:
        raise SystemExit(f"derive_jacobians: F has entries outside the C core's block structure: {extra}")


def check_sensor_structure(FS: sp.Matrix) -> None:
    """The scale-factor / g-sensitivity columns: only the velocity / attitude rows and the Gauss-Markov diagonal
    (the C core's phi_blocks reads the blocks of ins_gen_F_sf and the diagonal)."""
    allowed = set()
    for i in range(3):
        assert FS[NX + i, i] == -its and FS[NX + 3 + i, 3 + i] == -its
        allowed |= {(NX + i, i), (NX + 3 + i, 3 + i)}
        allowed |= {(6 + i, j) for j in range(3)} | {(3 + i, 3 + j) for j in range(3)}
        allowed |= {(6 + i, 6 + j) for j in range(9)}
    extra = [(i, j) for i, j, _ in _entries(FS) if (i, j) not in allowed]
    if extra:
        raise SystemExit(f"derive_jacobians: the sensor columns of F have unexpected entries: {extra}")


def generate() -> tuple[str, str]:
    F = derive_F()
    check_structure(F)
    FS = derive_F_sensor()
    check_sensor_structure(FS)
    H = derive_H()
    FR = derive_F_omega_rv()
    HA = derive_H_aids()
    for name, M in HA.items():
        assert M.cols == (3 if name == "mag_bias" else NX + HA_EXTRA[name]), name
    return gen_c(F, H, FS), gen_py(F, H, FS, FR, HA)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if a checked-in generated file differs")
    a = ap.parse_args(argv)
    c_src, py_src = generate()
    bad = []
    for path, text in ((C_OUT, c_src), (PY_OUT, py_src)):
        if a.check:
            if not path.exists() or path.read_text() != text:
                bad.append(os.path.relpath(path, ROOT))
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
    if bad:
        print(f"derive_jacobians: out of date (run firmware_ref/tools/derive_jacobians.py): {', '.join(bad)}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
