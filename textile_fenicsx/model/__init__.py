"""The textile model, pure geometry with no DOLFINx (DESIGN.md section 3): the cell and its yarns
(textile, yarn, yarn_sections, sections), geometric queries (queries, rays), fibre data (fibres),
builders (weaves, plies, coupon) and the model's measures (metrics).
"""
