"""The pictures' colours, RGB: the lot, the cars, the rays, and the overlay's label."""

ASPHALT = (52, 54, 60)
WALL = (150, 150, 150)
SLOT_LINE = (225, 225, 225)
PARKED = (70, 110, 175)
GOAL = (60, 170, 90)
EGO = (235, 95, 40)
HEADING = (255, 240, 200)
RAY = (235, 215, 90)
HIT = (255, 60, 60)
TEXT = (20, 20, 20)
LABEL = (255, 255, 255)
