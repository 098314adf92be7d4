"""Process and measurement models: pure functions of the filter state, one per module."""
