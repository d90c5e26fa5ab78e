"""The state vector of the three-control-volume tank model and its layout.

``s = [m_v, m_l, u_v, u_l, T_w, V_v, V_l]`` (paper, section 2), in SI units:

=====  ==========================================  ========
index  quantity                                    unit
=====  ==========================================  ========
0      vapour (ullage) mass ``m_v``                kg
1      liquid mass ``m_l``                         kg
2      vapour specific internal energy ``u_v``     J/kg
3      liquid specific internal energy ``u_l``     J/kg
4      wall temperature ``T_w``                    K
5      vapour volume ``V_v``                       m^3
6      liquid volume ``V_l``                       m^3
=====  ==========================================  ========

Tensors carry any leading batch dimensions, usually ``(env, 7)``.
"""

from __future__ import annotations

M_V, M_L, U_V, U_L, T_W, V_V, V_L = range(7)
N_STATE = 7

STATE_NAMES = ("m_v_kg", "m_l_kg", "u_v_J_per_kg", "u_l_J_per_kg", "T_w_K", "V_v_m3", "V_l_m3")

__all__ = ["M_V", "M_L", "U_V", "U_L", "T_W", "V_V", "V_L", "N_STATE", "STATE_NAMES"]
