"""Numerical tolerances, in one place.

Each value is the documented default of the keyword argument of the same name in the
functions that use it; pass another value there to override it for one call.
"""

#: Relative rank tolerance: a singular value ``s`` counts when ``s > RANK_RTOL * max(1, s_max)``.
#: Matrices in problem files are given with a few digits; 1e-9 separates "zero" from
#: "small" far above the round-off of products like ``C @ E`` (about 1e-16).
RANK_RTOL = 1e-9

#: Strictness margin of the LMIs: a strict inequality ``F(x) > 0`` is solved as
#: ``F(x) >= LMI_MARGIN * I``; it is 100x the solver tolerance below.
LMI_MARGIN = 1e-6

#: Feasibility and gap tolerances asked of CLARABEL.
SOLVER_TOL = 1e-8

#: A bounded "largest margin" problem (``max t`` with every LMI ``>= t I`` and the Lyapunov matrices
#: normalised by their trace, solved by CLARABEL to optimality in well-conditioned coordinates)
#: proves that no certificate exists when ``t`` is below ``-MARGIN_PROOF_RTOL`` times the Lyapunov
#: matrices' mean eigenvalue: 100x the solver tolerance, so that its own error cannot flip the sign.
MARGIN_PROOF_RTOL = 100 * SOLVER_TOL

#: CLARABEL's tolerances for a largest-margin problem (:meth:`uiofmu.lmi.LmiSystem.largest_margin`): bounded and
#: strictly feasible by construction, it is solved far more finely than the design LMIs.
MARGIN_SOLVER_TOL = 1e-10

#: The least margin with which a point of largest margin certifies (:meth:`uiofmu.lmi.LmiSystem.largest_margin`):
#: relative to the mean eigenvalue of the normalised Lyapunov matrices, 100x :data:`MARGIN_SOLVER_TOL`.
MARGIN_DECISION_RTOL = 100 * MARGIN_SOLVER_TOL

#: A ``"max"`` search passes a value when its largest margin (relative, as above) is at least a threshold of
#: its own problem: this fraction of the margin at the first value that passed (the easy end of the range),
#: within :data:`MARGIN_DECISION_RTOL` and :data:`SEARCH_MARGIN_CAP`. A margin moves with the BLAS kernel in
#: the digits the solver does not resolve (measured between kernels: 1e-11 to 4e-8 next to the edge), where a
#: feasible point the solver happened to stop at moves with everything; the threshold keeps the decisions
#: above those moves, and its point, divided by its margin, far enough from the edge for a re-check that
#: holds alike on every machine. Some problems never reach a margin of 1e-6 (a vertex the searched value
#: does not move can cap it), hence a fraction of their own.
SEARCH_MARGIN_FRACTION = 0.01

#: :meth:`uiofmu.lmi.LmiSystem.least_at_margin` solves its problem twice, the second time with the margin held
#: this much higher (relative): the optimum barely moves (its figure by about this much), while an answer the
#: solver did not converge to moves by percents (measured: 334 to 478 between kernels on a plant at the edge).
HELD_PROBE = 1e-6

#: The further solves of :meth:`uiofmu.lmi.LmiSystem.least_at_margin`, in multiples of :data:`HELD_PROBE`, made in
#: turn until two figures agree: CLARABEL gives up on some (InsufficientProgress) and stops short on others (an
#: answer 0.34 % above two that agreed to 1e-4, on a plant at the edge), so a third and a fourth decide where two
#: disagree.
HELD_PROBES = (1, -1, 2, -2)

#: The first solves of :meth:`uiofmu.lmi.LmiSystem.least_at_margin` of which one at least must give a point that
#: verifies before further solves are made: where none does, CLARABEL does not solve the held problem (it gave up,
#: InsufficientProgress, or ended AlmostSolved at points the re-check refuses), and which of the later solves verify
#: is the BLAS kernel's rounding. Measured on two fresh plants next to the edge, five solves each: an lti-uio plant
#: (decay 0.9754) got 2 points that verify and agree (9.7965) under SkylakeX, none under Prescott, Haswell and
#: Sandybridge; an ltv-auid plant (2.987) got the 4th and 5th under Prescott and Haswell, one under SkylakeX and
#: Sandybridge. Neither had a point of its first two verify under any kernel; no other plant of
#: ``tests/same_answers.py`` or of 96 fresh ones reproduced its figure under one kernel and failed its first two
#: solves under another.
HELD_OPENING = 2

#: The two figures of :meth:`uiofmu.lmi.LmiSystem.least_at_margin` agree, and the figure counts as the problem's
#: (printed to 2 significant digits), when they differ by at most this, relative.
HELD_AGREEMENT = 1e-3

#: A ``"max"`` search decides a value whose largest margin lies within this factor of its threshold (either
#: side) again (:data:`MARGIN_PROBES`: its rounding twin, then a value :data:`MARGIN_PROBE` away), and the value
#: counts only when two of those margins agree to :data:`MARGIN_AGREEMENT`: on plants whose LMIs need gains of 1e8
#: the margin moved by a factor 8 between BLAS kernels (1.5e-7 against 1.1e-6), so a threshold between them decided
#: the search by the machine; the same solve at a value 1e-9 away disagrees as much, and such a value is refused on
#: every machine alike.
MARGIN_NEAR = 10.0

#: See :data:`MARGIN_NEAR` (relative to the value).
MARGIN_PROBE = 1e-9

#: See :data:`MARGIN_NEAR` (relative to the larger margin).
MARGIN_AGREEMENT = 0.5

#: The probes of a value :data:`MARGIN_NEAR` its threshold, made in turn until two certified solves agree (the first
#: value that passes: every one, each agreeing with it; :func:`uiofmu.lmi._judged`): ``(twin, away)``, ``twin`` a
#: solve with the variables in reversed order (:func:`uiofmu.conic.rounding_twin`), ``away`` the value moved by that
#: many :data:`MARGIN_PROBE`. A solve 1e-9 away rounds as the first does, so on one machine it moves with it; the
#: twin rounds as another kernel would: on a campaign plant whose point 1e-9 away failed its re-check under one
#: kernel only (its decay search ended at 0.625 there, 0.5625 elsewhere), the twin's margin (6.99e-9 against
#: 7.22e-9) and point agree, and the search ends at 0.5625 on every kernel.
MARGIN_PROBES = ((True, 0), (False, 1))

#: The first value that passes a ``"max"`` search away from theory's limit sets its threshold
#: (:data:`SEARCH_MARGIN_FRACTION` of its margin), so its margin is decided again by every one of :data:`MARGIN_PROBES`
#: whatever its size, and counts only when each agrees with it to this (relative to the larger); otherwise the search
#: stops there and refuses. On a badly scaled plant needing gains of 1.6e6, CLARABEL's inaccurate optima put the
#: margin anywhere in -1.2e-6..9e-7 along the range, and the first value's two solves came out 75 % apart under one
#: BLAS kernel, of opposite signs under another; on a plant needing gains of 1e7 whose margins are resolved well
#: enough for the same search on every kernel, they came out up to 10 % apart under one kernel. Two margins that
#: both set the largest threshold (:data:`SEARCH_MARGIN_CAP`) need not agree: the threshold is the same whatever
#: their digits (an ltv-auid plant's were 2.4e-4 to 6.2e-4 by kernel and probe).
FIRST_MARGIN_AGREEMENT = 0.5

#: The largest threshold of a ``"max"`` search (see :data:`SEARCH_MARGIN_FRACTION`).
SEARCH_MARGIN_CAP = 1e-6

#: A ``"max"`` search stops narrowing its bracket when the largest margins at its two ends differ by less than
#: this many times its threshold: a bracket narrower than that is decided by the solver's last digits where the
#: margin is flat near the edge, so its end would move with the BLAS kernel.
SEARCH_RESOLUTION = 4.0

#: The independent re-check accepts a strict LMI when its smallest eigenvalue, evaluated
#: with numpy at the stored matrices, is at least ``VERIFY_FRACTION * LMI_MARGIN``.
VERIFY_FRACTION = 0.1

#: A definiteness check at the stored matrices (``Q > 0`` by its smallest eigenvalue) is decided only
#: with margin over its own rounding: it holds when ``eig_min(Q) >= ROUNDING_FACTOR * floor``, ``floor``
#: the bound of the rounding error of evaluating ``Q`` and its eigenvalue in double precision, derived
#: from the sizes and magnitudes of the matrices (:func:`uiofmu.certificate.rounding_floor`). With 2,
#: a check that holds proves the exact inequality at the stored matrices whatever the BLAS kernel, and
#: a verdict closer to the edge is a refusal that says so, on every machine alike.
ROUNDING_FACTOR = 2.0

#: Equalities and non-strict LMIs at the solver's point are judged relative to the size of the
#: point, as CLARABEL's own tolerance is: a residual (or a negative eigenvalue) is accepted up to
#: ``max(VERIFY_FRACTION * LMI_MARGIN, POINT_RTOL * max(1, |x|_max))``, ``|x|_max`` the largest
#: entry of any variable. Strict LMIs keep the absolute rule above, and the decision stays with
#: the re-check at the stored matrices.
POINT_RTOL = 1e-9

#: Largest accepted residual of an identity the design must satisfy exactly
#: (decoupling (I + MC)E = 0, PA - NP - LC = 0, ...), relative to the norms involved.
IDENTITY_RTOL = 1e-9

#: A figure read off a certified point (the overshoot bound) is printed to 4 significant digits when the point
#: is an optimum the solver reached to its full tolerance, with the normalisations it may violate by up to
#: :data:`POINT_RTOL` times its largest entry violated by at most this (the ratio then moves by less than
#: half of it, far inside the 4th digit's 1e-3), or when it is a closed form; otherwise to 2 (an optimum
#: reached only "inaccurately", a point of largest margin, a point reused from another value). The card
#: keeps the bound of its own matrices to full precision, and the digits its design determines.
FIGURE_RTOL = 1e-4

#: Bisection tolerance of a "max" search, on the searched parameter.
SEARCH_TOL = 1e-4

#: A communication step h matches a design interval H when ``|h - H| <= STEP_RTOL * H``.
STEP_RTOL = 1e-6

#: A step h is also the admissible step H when ``|h - H|`` is at most this many units in the last place of the
#: current time t: a master that computes h as the difference of two times loses that much (at t = 1e7 s the
#: ulp is 1.9e-9 s, more than STEP_RTOL of a 1 ms step).
STEP_ULPS = 4

#: ... as long as those ulps are at most this fraction of H: where the time no longer resolves the step (t = 1e16 s
#: has an ulp of 2 s), only STEP_RTOL applies, and a step of any length is not taken for H.
STEP_ULPS_LIMIT = 1e-3

#: A step shorter than this fraction of the smallest admissible step is rounding, not a step (OMSimulator ends a
#: run with h = 1.4e-12 s to close the gap to its stop time): the FMU accepts it and leaves its state unchanged.
TINY_STEP_RTOL = 1e-9

#: A continuous-time invariant zero is "stable" when its real part is below ``-ZERO_MARGIN``;
#: a discrete-time one when its modulus is below ``1 - ZERO_MARGIN``.
ZERO_MARGIN = 1e-9

#: A placeable mode whose relative PBH margin is below this needs gains above about its inverse
#: (1e4): ``check`` warns, and a failed design names it.
WEAK_MARGIN = 1e-4

#: Significant digits of a certified noise gain (:mod:`uiofmu.noise`, rounded up).
NOISE_DIGITS = 3

#: A closed-form design's certified noise gain is the problem's to :data:`NOISE_DIGITS` when its re-check holds at
#: its first figure (the H-infinity norm's, rounded up) with each inequality's smallest eigenvalue at least this
#: many times what the rounding of its evaluation can move it. A lemma held by less is held by the rounding of its
#: storage ``X``: on a plant next to the edge, the values were 1.5e-14 to 1.5e-11 (0.25 to 260 times that floor, of
#: either sign, the sign moving with the BLAS kernel); on the closed-form designs of tests/same_answers.py, 9.5e6
#: times the floor and more.
NOISE_ROOM = 1e4
