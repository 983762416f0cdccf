"""verify: an export drawn by the runtime against the offline reference; the batch's HTML report."""
