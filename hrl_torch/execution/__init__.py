"""Layer 3: the Task-Stack, its pushes and pops, and the SMDP transition schema."""
