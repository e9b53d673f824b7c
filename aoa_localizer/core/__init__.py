"""The bottom layer: declarations every package may import (it imports nothing of the project)."""
