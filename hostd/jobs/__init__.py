"""Jobs and their store: the job folder, intake, the job store and each job's life and outcome."""
