"""Floor 8, goals for a team on your own map: the goal call (:mod:`.assign`, over :mod:`.grid`,
:mod:`.decision`, :mod:`.answer` and :mod:`.team`), ROS ``OccupancyGrid`` messages
(:mod:`.occupancy_msg`) and the HTTP service (:mod:`.serve`, over :mod:`.settings`, :mod:`.schema`,
:mod:`.app`, :mod:`.pool` and :mod:`.limits`).

Imports the planners and the floors below.
"""
