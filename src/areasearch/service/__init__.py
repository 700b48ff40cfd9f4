"""Floor 8, goals for a team on your own map: the assignment core (:mod:`.assign`), ROS
``OccupancyGrid`` messages (:mod:`.occupancy_msg`) and the HTTP service (:mod:`.serve`).

Imports the planners and the floors below.
"""
