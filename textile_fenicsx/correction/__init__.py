"""From the plates' solution to the corrected model, and its check (DESIGN.md sections 7-7c):
binders cut into crowns and legs (legs, loops), the thickness that follows the slope (slopes),
the corrected yarns (correct, stations), legs fitted into their gaps (leg_fit), tight bends
opened (bend_fit), the check (verify).
"""
