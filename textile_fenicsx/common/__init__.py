"""What every stage shares: errors (exit codes), limits (bounds on every input), the memory guard,
MPI's excepthook (parallel), Ctrl-C inside native code (interrupts), files that appear whole (files),
PETSc options under a prefix while they are read (petsc).
"""
