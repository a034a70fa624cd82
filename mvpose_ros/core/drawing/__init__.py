"""Drawing people: their colours and sizes, overlays on camera images, rendered videos, line plots."""
