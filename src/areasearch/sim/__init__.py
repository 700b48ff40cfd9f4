"""Floor 1, the world: maps and procedural layouts, the train/val/test split, the robots' motion and
collision rule, the depth camera, the mapper, targets and metrics, and the top-down pictures.

Imports only the shared leaves (:mod:`areasearch.config`, :mod:`areasearch.errors`,
:mod:`areasearch.inputs`, :mod:`areasearch.folderlock`).
"""
