"""The names the agent reports to the runner and the trial report: what each ``act`` was doing,
and which decisions it counts. Torch-free, so the report reads them without importing the agent."""

ACTIVITIES = ("start_scan", "exploration", "local_search", "pick", "carry", "place")
"""What an ``act`` can be doing: the start scan; exploring frontiers (rescue and revisits too);
local search of a candidate pick location or an extra view of a target candidate; the pick skill;
carrying the object while searching for the goal receptacle (its extra views too); the place skill."""

DECISION_COUNTS = ("global_with_candidates", "chose_candidate_before_f0", "chose_frontier_before_f0",
                   "chose_candidate_after_f0", "chose_frontier_after_f0", "extra_views_object",
                   "extra_views_goal", "gaze_point_visits", "gaze_point_views", "frontiers_given_up",
                   "claw_drops")
"""The integer counts of ``HeliosAgent.decision_stats()`` (besides ``local_search_sizes``)."""
