"""Validity: how far the particle picture agrees with linear elasticity.

:mod:`.fea` computes linear-elastic finite-element references (scikit-fem, plane stress) for
three cases with known answers — a cantilever with a tip load (Euler–Bernoulli), a plate with a
circular hole in uniaxial tension (Kirsch) and an L-bracket with a re-entrant corner — and
interpolates von Mises stress and strain at given points (the particles' original positions).
:mod:`.compare` holds the figures of agreement (rank correlation, hot-spot overlap, location of
the maximum). Part of the bench layer: it may import everything below it.

scikit-fem is an optional dependency (the ``fem`` extra): importing :mod:`.fea` without it raises
an ImportError that names the extra.
"""
