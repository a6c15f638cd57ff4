"""The report's sections: check points and statistics."""
