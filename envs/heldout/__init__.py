"""Held-out tasks (issue 33, Build 6): small tasks none of the registered defaults were tuned on.

Each module holds a torch-batched env and its exact model (the reference); the domains are in
``agents/heldout.py``, loaded with ``--domain-module agents.heldout`` as a user's plugin would
be (they are not registered with the built-in domains). ``docs/heldout.md`` has the references
and what the registered defaults reached.
"""
