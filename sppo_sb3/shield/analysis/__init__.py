"""Tools that measure a shielding rule: Theorem 1's bound, and a rule's decisions against a reference rule's."""
