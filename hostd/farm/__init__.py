"""The farm queue: one STL job for every printer of a farm, on a NATS JetStream cluster.

``needs`` (what a job needs, what a printer declares, why a job waits), ``records``
(a job's entry in the key-value bucket), ``model`` (checks of a submitted file),
``queue`` (the stream, buckets and object store, and the operations on them),
``agent`` (a daemon taking jobs for its printer).
"""
