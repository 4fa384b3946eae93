"""The studies behind the results pages: closed-loop tables and ablations, offline metrics of the learned parts, the
planner's direction promises, upstream roads; and the campaign shell scripts that run them resumably. README.md lists
them with the page each feeds."""
