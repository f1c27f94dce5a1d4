"""Layer 3, the Task-Stack and its pushes and pops, and the SMDP transition schema."""
