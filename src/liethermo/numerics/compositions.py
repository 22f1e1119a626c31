"""Symmetric compositions of a symmetric step of order 2 into orders 4 and 6,
shared by every model that composes its order-2 step (the top's variational
integrator and splitting, the Zeitlin fluid's splitting)."""

_G1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
_G0 = 1.0 - 2.0 * _G1
_D1 = 1.0 / (2.0 - 2.0 ** (1.0 / 5.0))
_D0 = 1.0 - 2.0 * _D1

_P4 = 1.0 / (4.0 - 4.0 ** (1.0 / 3.0))
#: Kahan & Li (1997), s9odr6a: γ₁ … γ₅, then γ₄ … γ₁
_KL = (0.39216144400731413928, 0.33259913678935943860, -0.70624617255763935981,
       0.082213596293550800230, 0.79854399093482996340)

#: factors h_i = f_i h of symmetric compositions of a symmetric step of order 2,
#: by (kind, order): "small_error" — Suzuki's five stages (1990; largest negative
#: substep −0.66 h) and Kahan & Li's nine (1997, s9odr6a); "triple_jump" —
#: Yoshida's triple jump (1990; −1.70 h) and its triple jump again
COMPOSITION_FACTORS = {
    ("small_error", 4): (_P4, _P4, 1.0 - 4.0 * _P4, _P4, _P4),
    ("small_error", 6): _KL + _KL[-2::-1],
    ("triple_jump", 4): (_G1, _G0, _G1),
    ("triple_jump", 6): tuple(d * g for d in (_D1, _D0, _D1) for g in (_G1, _G0, _G1)),
}
COMPOSITION_KINDS = ("small_error", "triple_jump")
