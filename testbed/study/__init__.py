"""The paper's study: the campaign of scenarios × methods × seeds and its report (`campaign`)."""

__all__: list[str] = []
