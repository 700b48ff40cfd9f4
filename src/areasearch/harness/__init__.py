"""Floor 6, the evaluation harness: paired seeded episodes of every method (:mod:`.evaluate`), their
tables and curves (:mod:`.report`) and animations (:mod:`.animate`).

Imports the planners, the environments and the floors below.
"""
