"""Shielding rules that learn where no model exists (Alg. 1 line 12): a cost critic, learned dynamics, and a rule on
SPPO's own latent model."""
