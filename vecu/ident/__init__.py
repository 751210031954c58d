"""System identification from a user's trace (issue 18): the throttle body of Vargas 2015 §III-B."""
