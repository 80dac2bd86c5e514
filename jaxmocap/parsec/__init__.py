"""PARSEC bodytrack's tracker (a wing of the core): its body model, likelihood, input folders and run."""
