"""The plate stage (DESIGN.md sections 4-6 and 9): each yarn's mid-surface meshed as a plate on the
projected mesh (mesh/), its energy terms in UFL (forms/), the contact solve (solver/), point
values of its fields (point_values) and manufactured solutions that verify the forms
(verification).
"""
