from trainers.distill.cli import main

main()
