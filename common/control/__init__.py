"""The paper's control method, pure numpy/scipy with no I/O.

Leader law (31), damping scheduler (40), observer (12), equivalent follower (29), reduced hybrid follower and its Poincare map (20)-(26), and the
online choice of (sigma_r, T, eps) (30).
"""
