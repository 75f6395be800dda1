"""Paper 002's distributed optimization framework (docs/equations.md, "Distributed gradient
framework"): every agent descends the sum of its edges' pairwise costs using only its own and its
neighbours' states (paper 002 eq. 5-8).

Modules, one job each, pure functions on arrays:

* :mod:`.reshaping`: the reshaping functions ``f_R, f_T, f_C, f_D`` and their conditions
  (paper 002 eq. 15, 21 and the sign condition of eq. 22-23);
* :mod:`.flow`: the generic gradient flow (eq. 7-8), its discrete update (Euclidean and on SO(3)
  through the exponential map), the projection of eq. 17, the step-size rule and the leader option;
* :mod:`.rotation`: rotation estimation (eq. 13-15);
* :mod:`.yaw`: its yaw-only case, relative yaws from reciprocal levelled bearings (fig. 6) and
  eq. 13-15 on SO(2) through :mod:`.rotation`;
* :mod:`.localization`: bearing-only and bearing + distance localization (eq. 16-17, 22);
* :mod:`.joint`: rotations, translations and scales together (eq. 13 + 16, mutual localization's
  third stage) and the three-stage run;
* :mod:`.formation`: bearing (+ distance) formation control (eq. 18-21, 23);
* :mod:`.metrics`: errors modulo the unobservable gauge (similarity / global rotation alignment).
"""
