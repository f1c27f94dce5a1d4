"""Layer 1: the task graph (Definition 3.1): subtasks, primitives, the compiled instance tree."""
