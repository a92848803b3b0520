"""The loop's numbers in plain words: where each threshold sits on the input, why a
candidate was or was not recommended, the round's verdict."""
