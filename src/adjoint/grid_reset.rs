//! Adjoint of stage 1, grid reset: no work. The forward sets the node mass and momentum to the
//! constant 0, so no gradient flows through it, and nothing is left to clear: the P2G adjoint
//! sets (not accumulates) the mass and momentum adjoints each substep, and consumes the grid
//! velocity adjoint, because P2G, not the reset, writes every node's velocity. The stage
//! therefore adds no system to the adjoint schedule (`add_adjoint_stage`).
