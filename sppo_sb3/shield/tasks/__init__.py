"""The built-in tasks' shielding rules: the Point Robot's, the Half-Cheetah height rule and the velocity tasks' rule."""
