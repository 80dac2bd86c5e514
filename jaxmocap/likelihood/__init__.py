"""The likelihood: cue energies, their Gibbs-form composition, per-layer schedules, map lookups, gradients."""
