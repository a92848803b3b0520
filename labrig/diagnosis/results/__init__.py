"""What the loop returns: a round's :class:`~labrig.diagnosis.results.diagnosis.Diagnosis`
(its ranked candidates), the error ladder, their JSON documents and figures."""
