"""Operator models, one module each: the model and its :data:`PART` (an entry point of ``bipedtele.operators``).

The contract, the context a part builds from and :func:`~bipedtele.leader.operator.make_operator`
are in :mod:`bipedtele.leader.operator`.
"""
