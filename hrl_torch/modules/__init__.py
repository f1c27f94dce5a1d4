"""Layer 4: what is learned.

Value tables, evaluation plans, heads, policies, tile coding and exploration schedules.
"""
