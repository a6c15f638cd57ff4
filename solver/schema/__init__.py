"""The job document: its pydantic schema (the public input contract) and the names it uses."""
